"""Job kinds of the depth service (imported by the API: keep it light)."""

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from contract.artifacts import ArtifactKind
from contract.kinds import TRAINING_PAGE, Inputs, JobKind, Output, Presentation
from contract.training import TrainSettings
from contract.views import TRAINING_REPORT_NAME
from services.lib.artifact_kinds import FORMATS

EPOCHS = 12

Network = Literal["teacher", "student"]
"""What ``depth.train`` trains: Monodepth2's network, or the student distilled from one."""
Supervision = Literal["stereo", "mono", "both", "depth", "lidar"]
"""What teaches a teacher (``teacher.py``)."""
DistillMethod = Literal["thesis", "vista"]
"""How a student learns from its teacher (``distill.py``)."""


class TrainParams(TrainSettings):
    network: Network = Field(
        "student",
        description="teacher: Monodepth2's network trained on the drives (adapting the `model` "
        "input when one is given); student: DeepLabv3+ with MobileNetV2 distilled from the "
        "`model` input.",
    )
    supervision: Supervision = Field(
        "depth",
        description="A teacher's: stereo (image_03/), mono (video, pose network), both, depth "
        "(the drives' depth maps) or lidar (the drives' velodyne/ scans through their "
        "calibration; simulated drives give depth/).",
    )
    method: DistillMethod = Field(
        "vista",
        description="A student's: thesis (L1 on the teacher's depth) or vista (log + gradients "
        "+ feature hints + photometric).",
    )
    width: int = Field(
        320,
        ge=64,
        le=4096,
        multiple_of=32,
        description="Training width, px (a multiple of 32; Monodepth2 trains at 640 × 192, "
        "vista's CPU default is 320 × 96).",
    )
    height: int = Field(
        96, ge=64, le=4096, multiple_of=32, description="Training height, px (a multiple of 32)."
    )
    epochs: int = Field(EPOCHS, ge=1, le=10_000, description="Passes over the frames.")
    batch: int = Field(8, ge=1, le=4096, description="Frames per step.")
    learning_rate: float = Field(3e-4, gt=0, le=1, description="Adam's step (cosine schedule).")


TRAIN = TrainParams.model_fields


class BuildSettings(BaseModel):
    """How ``vista depth build-default`` builds the model vista ships (``default_model``):
    its options come from here; the training size, batch and seed are ``depth.train``'s."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    sim_drives: int = Field(500, ge=2, description="Simulated stereo drives of three frames.")
    teacher_epochs: int = Field(8, ge=1, description="The simulator's teacher's passes.")
    adapt_epochs: int = Field(
        20, ge=1, description="Passes adapting the teacher by the real drive's LiDAR."
    )
    adapt_sim_drives: int = Field(
        40, ge=1, description="Simulated drives mixed into the adaptation."
    )
    student_epochs: int = Field(8, ge=1, description="The student's passes.")
    student_sim_drives: int = Field(
        300, ge=1, description="Simulated drives the student also learns on."
    )
    width: int = TRAIN["width"]
    height: int = TRAIN["height"]
    batch: int = TRAIN["batch"]
    seed: int = TRAIN["seed"]
    threads: int = Field(2, ge=1, le=256, description="Threads for torch.")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), px: every stage's training size."""
        return self.width, self.height


class PredictParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    int8: bool = Field(
        False,
        description="Quantize the model to int8 first (weights and activations, onnxruntime's "
        "QOperator format: about 2× faster on 2 cores), calibrated on these images; check it on "
        "frames with ground truth: on some models and frames it costs much accuracy.",
    )
    clouds: bool = Field(
        True, description="Write each image's point cloud (PLY, mm, the camera's frame)."
    )


MODEL = Output("model", "depth.onnx")
TRAINING_REPORT = Output("report", TRAINING_REPORT_NAME)
DEPTH_MAP = Output("depth", "{stem}.depth.png", per_input=True)
PREVIEW = Output("plot", "{stem}.color.png", per_input=True)
CLOUD = Output("cloud", "{stem}.ply", per_input=True)
PREDICT_REPORT = Output("report", "depth.json")
ERROR_MAP = Output("plot", "{stem}.error.png", per_input=True)

DEPTH_TRAIN = JobKind(
    name="depth.train",
    queue="training",
    handler="services.depth.jobs:train_job",
    shows=TRAINING_PAGE,
    params=TrainParams,
    description=(
        "Trains a monocular depth network on `drive` archives (KITTI layout) or `image`s: a "
        "teacher (Monodepth2's network, self-supervised by stereo or video or supervised by "
        "depth or LiDAR; from scratch, or adapting a teacher `model`) or a student (DeepLabv3+ MobileNetV2, 2.67 M parameters) distilled from a "
        "teacher `model`; writes the ONNX `model` (its spec, training and validation in its "
        "metadata) and the training's history."
    ),
    inputs=(
        Inputs(("drive", "image"), "drives (zip or tar, KITTI layout) or images", max=None),
        Inputs(
            ("model",),
            "the teacher (a student's to learn from; a teacher's to adapt, optional)",
            min=0,
            needed_when=("network", ("student",)),
            made_by=("depth.train",),
        ),
    ),
    outputs=(MODEL, TRAINING_REPORT),
)

DEPTH_PREDICT = JobKind(
    name="depth.predict",
    queue="depth",
    handler="services.depth.jobs:predict_job",
    shows=Presentation(
        page="services.depth.views:predict_view", scene="services.depth.views:predict_scene"
    ),
    params=PredictParams,
    description=(
        "Depth for an inspection's images (`image`s, or `drive` archives' left images) by a "
        "depth `model` (without one, the model vista ships): per image a KITTI depth PNG (uint16, metres × 256) at its own size, a "
        "colour preview and the camera-frame point cloud (PLY, mm; the images' `calibration` when given), and a report with each "
        "image's time and median depth; with ground-truth `depth` maps named as the images, "
        "each image's seven metrics (median-scaled, Garg crop) and an error map."
    ),
    inputs=(
        Inputs(
            ("model",),
            "a depth model (vista's, or ONNX with vista's metadata); none: the shipped one",
            min=0,
        ),
        Inputs(("image", "drive"), "the images", max=None),
        Inputs(
            ("calibration",),
            "the images' camera; none: KITTI's (a drive has its own)",
            min=0,
        ),
        Inputs(
            ("depth",),
            "ground truth for the images (KITTI depth PNGs named as the images): each "
            "image scored by the seven metrics (median-scaled) and its error drawn",
            min=0,
            max=None,
        ),
    ),
    outputs=(DEPTH_MAP, PREVIEW, CLOUD, ERROR_MAP, PREDICT_REPORT),
)

KINDS = (DEPTH_TRAIN, DEPTH_PREDICT)
ARTIFACT_KINDS = (
    ArtifactKind(
        "depth",
        "A depth map in KITTI's convention: 16-bit grey PNG, metres × 256, 0 = none.",
        f"{FORMATS}:inspect_depth_png",
    ),
    ArtifactKind(
        "calibration",
        "A camera calibration: vista's calib.json (K or P_rect_02, optional baseline_m or "
        "P_rect_03) or KITTI's calib_cam_to_cam.txt; depth.predict places its images' clouds "
        "with it.",
        "services.depth.drive:inspect_calibration",
    ),
    ArtifactKind(
        "drive",
        "A camera drive in KITTI's layout as a zip or tar: image_02/ and its calibration "
        "(calib.json or calib_cam_to_cam.txt), with image_03/, depth/, poses.txt as known.",
        "services.depth.drive_archive:inspect_drive_artifact",
    ),
)
"""The kinds of file only this service knows (the shared ones: ``services.lib.artifact_kinds``)."""

CLI = "services.depth.cli:register"
"""Its commands: `vista depth …` (``register(app, simulate_app, bench_app)``)."""

SAMPLE_RUN = "services.depth.sample:sample_run"
"""A run of its jobs on files it makes (``contract.samples``): `vista bench clients` draws their pages and scenes."""
