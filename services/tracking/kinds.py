"""Job kinds of the tracking service (imported by the API: keep it light)."""

import re
from typing import Annotated, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from contract.artifacts import ArtifactKind
from contract.kinds import TRAINING_PAGE, Inputs, JobKind, Output, Presentation
from contract.training import TrainSettings
from contract.views import TRAINING_REPORT_NAME

DETECTOR_EPOCHS = 12
DETECTOR_LEARNING_RATE = 2e-3
DETECTOR_BATCH = 8
DETECTOR_MAX_BATCH = 256
FINE_TUNE_EPOCHS = 10
FINE_TUNE_LEARNING_RATE = 5e-4
SIAMESE_EPOCHS = 20
SIAMESE_LEARNING_RATE = 1e-3
SIAMESE_BATCH = 64
"""How each network trains unless told otherwise (``network_defaults``): the detector from
scratch, the detector fine-tuned, SC3D's Siamese encoder."""

MAX_FRAME = 10_000_000
BoxNumber = Annotated[float, Field(ge=-1e4, le=1e4, allow_inf_nan=False)]
"""A box's size (m), position (m) or rotation (rad): finite and within 10 km."""

RESET_POLICY = re.compile(r"never|every:[1-9]\d*|adaptive(:\d+(\.\d+)?)?")
SEQUENCE = Inputs(
    ("lidar",),
    "a LiDAR sequence: a zip or tar of velodyne/NNNNNN.bin and calib.txt (label_02.txt, poses.txt as known)",
)

TrackerName = Literal["geometric", "siamese"]
DetectorName = Literal["geometric", "learned"]
TRACKERS: tuple[str, ...] = get_args(TrackerName)
DETECTORS: tuple[str, ...] = get_args(DetectorName)

DETECTOR_DESCRIPTION = "learned: the BEV network — vista's shipped model, or a `model` input (--detector-model); trained on simulated drives and fine-tuned on KITTI's labelled scans, on real scans it never saw it found 0.87 of the cars within 40 m at precision 0.82, in 22 ms a scan (the geometric detector: 0.65 and 0.53, in 170 ms). geometric: ground, clusters, L-shape boxes scored by shape — no model, for a sensor no model fits."


class TrackParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    track_id: int | None = Field(
        None,
        ge=0,
        le=2**31 - 1,
        description="Track this labelled object (label_02's track id) over its frames.",
    )
    init_box: list[BoxNumber] | None = Field(
        None,
        min_length=7,
        max_length=7,
        description="Or start from this KITTI camera box: h, w, l, x, y, z (metres), rotation_y (radians).",
    )
    start_frame: int | None = Field(
        None,
        ge=0,
        le=MAX_FRAME,
        description="With init_box: the frame it is in (default the first).",
    )
    end_frame: int | None = Field(
        None, ge=0, le=MAX_FRAME, description="With init_box: the last frame (default the last)."
    )
    reset: str = Field(
        "adaptive:10",
        description="adaptive[:BUDGET] (the default: the detector only when the tracker is unsure, on at most BUDGET percent of the frames — on the real drive and the simulated bench never below the tracker alone, at under 1 % of the frames for the geometric tracker), every:N (the thesis's fixed frequency 1/N) or never.",
    )
    tracker: TrackerName = Field(
        "geometric",
        description="geometric: point-model registration; siamese: SC3D (needs its encoder: a `model` input, or --siamese-model on the command line).",
    )
    detector: DetectorName = Field("learned", description=DETECTOR_DESCRIPTION)

    @field_validator("reset")
    @classmethod
    def _reset_policy(cls, value: str) -> str:
        if not RESET_POLICY.fullmatch(value):
            raise ValueError(
                f"{value!r} is not a reset policy: give adaptive[:BUDGET] (a percentage), "
                "every:N (N a whole number from 1) or never"
            )
        return value

    @model_validator(mode="after")
    def _one_target(self) -> "TrackParams":
        if (self.track_id is None) == (self.init_box is None):
            raise ValueError(
                "give the target either by track_id (a labelled track) or by init_box (its box), "
                "one of them"
            )
        if self.init_box is not None and min(self.init_box[:3]) <= 0:
            raise ValueError("init_box's h, w and l must be positive")
        return self


class DetectParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    detector: DetectorName = Field("learned", description=DETECTOR_DESCRIPTION)
    threshold: float | None = Field(
        None, ge=0, le=1, description="The lowest score kept (default: the detector's own)."
    )


class TrainParams(TrainSettings):
    network: Literal["detector", "siamese"] = Field(
        "detector", description="detector: the BEV car detector; siamese: SC3D's PointNet encoder."
    )
    epochs: int | None = Field(
        None,
        ge=1,
        le=10_000,
        description=f"Passes (default {DETECTOR_EPOCHS} for the detector, {FINE_TUNE_EPOCHS} to fine-tune it, {SIAMESE_EPOCHS} for the Siamese).",
    )
    learning_rate: float | None = Field(
        None,
        gt=0,
        le=1,
        description=f"Adam's step (default {DETECTOR_LEARNING_RATE:g} for the detector, {FINE_TUNE_LEARNING_RATE:g} to fine-tune it, {SIAMESE_LEARNING_RATE:g} for the Siamese).",
    )
    batch: int | None = Field(
        None,
        ge=1,
        le=4096,
        description=f"Samples a step (default {DETECTOR_BATCH} windows for the detector, at most {DETECTOR_MAX_BATCH}; {SIAMESE_BATCH} model–candidate pairs for the Siamese, at least 2).",
    )
    fine_tune: bool = Field(
        False,
        description="detector only: fine-tune a model — a `model` input (--from on the command line), or else vista's shipped detector — on the sequences instead of training from scratch.",
    )
    window: int = Field(
        224,
        ge=64,
        le=2048,
        description="detector only: the training window, cells of 0.2 m (a multiple of 16).",
    )
    windows: int = Field(
        512,
        ge=1,
        le=1_000_000,
        description="detector only: training windows an epoch at least (few scans repeat).",
    )
    frame_step: int = Field(
        2, ge=1, le=1000, description="detector only: every n-th labelled frame of a sequence."
    )
    paste: int = Field(
        8,
        ge=0,
        le=50,
        description="detector only: the most cars pasted into a training scan (0: none).",
    )
    samples: int = Field(
        6000, ge=16, le=10_000_000, description="siamese only: model–candidate pairs an epoch."
    )
    licence: str | None = Field(
        None,
        max_length=500,
        description="The training data's licence, written into the model's metadata (KITTI's is CC BY-NC-SA 3.0).",
    )

    @field_validator("window")
    @classmethod
    def _whole_blocks(cls, value: int) -> int:
        if value % 16:
            raise ValueError(f"{value} is not a multiple of 16 cells")
        return value

    @model_validator(mode="after")
    def _batch_of_the_network(self) -> "TrainParams":
        if self.network == "detector" and (self.batch or 0) > DETECTOR_MAX_BATCH:
            raise ValueError(f"the detector takes at most {DETECTOR_MAX_BATCH} windows a step")
        if self.network == "siamese" and self.batch == 1:
            raise ValueError("the Siamese encoder needs at least 2 pairs a step")
        return self


def network_defaults(params: TrainParams) -> TrainParams:
    """``params`` with the passes, the step and the batch it leaves ``None`` set to the
    network's own: the detector's from scratch or fine-tuned, the Siamese encoder's."""
    if params.network == "siamese":
        epochs, rate, batch = SIAMESE_EPOCHS, SIAMESE_LEARNING_RATE, SIAMESE_BATCH
    elif params.fine_tune:
        epochs, rate, batch = FINE_TUNE_EPOCHS, FINE_TUNE_LEARNING_RATE, DETECTOR_BATCH
    else:
        epochs, rate, batch = DETECTOR_EPOCHS, DETECTOR_LEARNING_RATE, DETECTOR_BATCH
    return params.model_copy(
        update={
            "epochs": params.epochs or epochs,
            "learning_rate": params.learning_rate or rate,
            "batch": params.batch or batch,
        }
    )


TRACK_REPORT = Output("report", "track.json")
TRACK_PLOT = Output("plot", "track.png")
EVALUATION = Output("report", "evaluation.json")
DETECTIONS = Output("report", "detections.json")
DETECTIONS_IMAGE = Output("plot", "{stem}.detections.png", per_input=True)
MODEL = Output("model", "tracking.onnx")
TRAINING_REPORT = Output("report", TRAINING_REPORT_NAME)

TRACK = JobKind(
    name="tracking.track",
    aliases=("track",),
    queue="tracking",
    handler="services.tracking.jobs:track_job",
    shows=Presentation(
        page="services.tracking.views:track_view", scene="services.tracking.views:track_scene"
    ),
    params=TrackParams,
    description=(
        "Tracks one car through a `lidar` sequence (thesis 5.1): the tracker every frame, the "
        "detector when the reset policy says so; writes TRACK.json (each frame's box in the "
        "camera and LiDAR frames, confidence, whether the detector ran), a plot, and with the "
        "sequence's labels the One-Pass Evaluation (Success, Precision)."
    ),
    inputs=(
        SEQUENCE,
        Inputs(
            ("model",),
            "the Siamese encoder and/or the learned detector, as the params need",
            min=0,
            max=2,
        ),
    ),
    outputs=(TRACK_REPORT, TRACK_PLOT, EVALUATION),
)

DETECT = JobKind(
    name="tracking.detect",
    queue="tracking",
    handler="services.tracking.jobs:detect_job",
    shows=Presentation(
        page="services.tracking.views:detect_view", scene="services.tracking.views:detect_scene"
    ),
    params=DetectParams,
    description=(
        "Finds the cars in every scan of a `lidar` sequence (thesis 5.1's detector) and writes "
        "DETECTIONS.json (each scan's boxes in the LiDAR frame with their scores, their 2D "
        "boxes in camera 2, the time a scan); with the sequence's labels each box is judged "
        "(recall within 40 m, precision in the camera's view, BEV IoU ≥ 0.5) and the cars "
        "missed are listed; with camera images named as the scans, each image with its boxes."
    ),
    inputs=(
        SEQUENCE,
        Inputs(
            ("image",),
            "camera 2's images of some scans, named as the scans (0000000042.png for velodyne/0000000042.bin)",
            min=0,
            max=None,
        ),
        Inputs(("model",), "the learned detector to use instead of vista's", min=0, max=1),
    ),
    outputs=(DETECTIONS, DETECTIONS_IMAGE),
)

TRACK_TRAIN = JobKind(
    name="tracking.train",
    aliases=("track.train",),
    queue="training",
    handler="services.tracking.jobs:train_job",
    shows=TRAINING_PAGE,
    params=TrainParams,
    description=(
        "Trains the learned car detector or SC3D's Siamese encoder on labelled `lidar` "
        "sequences and writes it as an ONNX `model` (its metadata: architecture, data, "
        "validation) with the training's history."
    ),
    inputs=(
        Inputs(("lidar",), "labelled LiDAR sequences (label_02.txt)", max=None),
        Inputs(("model",), "with fine_tune: the detector to start from", min=0, max=1),
    ),
    outputs=(MODEL, TRAINING_REPORT),
)

KINDS = (TRACK, DETECT, TRACK_TRAIN)
ARTIFACT_KINDS = (
    ArtifactKind(
        "lidar",
        "A LiDAR sequence in KITTI's formats as a zip or tar: velodyne/NNNNNN.bin and "
        "calib.txt, with label_02.txt and poses.txt as known.",
        "services.tracking.lidar_archive:inspect_lidar_artifact",
    ),
)
"""The kinds of file only this service knows (the shared ones: ``services.lib.artifact_kinds``)."""

CLI = "services.tracking.cli:register"
"""Its commands: `vista tracking …` (``register(app, simulate_app, bench_app)``)."""

SAMPLE_RUN = "services.tracking.sample:sample_run"
"""A run of its jobs on files it makes (``contract.samples``): `vista clients bench` draws their pages and scenes."""
