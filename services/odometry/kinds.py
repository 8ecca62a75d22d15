"""Job kinds of the odometry service (imported by the API: keep it light)."""

from typing import Literal, get_args

from pydantic import BaseModel, ConfigDict, Field

from contract.artifacts import ArtifactKind
from contract.kinds import TRAINING_PAGE, Inputs, JobKind, Output, Presentation
from contract.training import TrainSettings
from contract.views import TRAINING_REPORT_NAME

Method = Literal["vista", "phase", "oenet"]
METHODS: tuple[str, ...] = get_args(Method)
"""How a run estimates the motions, in the order the bench lists them."""

OENET_EPOCHS = 40
OENET_LEARNING_RATE = 0.02
"""OE-Net's training by default: about an hour on 2 cores for the bench's 12 000 pairs."""

SEQUENCE = Inputs(
    ("frames",),
    "a frame sequence: a zip or tar of the PNG frames with camera.json (truth.tum optional)",
)


class OdometryParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    method: Method = Field(
        "vista",
        description="vista: direct alignment at full resolution (no training needed); phase: "
        "phase correlation with a Fourier–Mellin turn (the classical peer); oenet: the "
        "thesis's network (needs its model: a `model` input, or --model on the command line).",
    )


class TrainParams(TrainSettings):
    arch: Literal["oenet"] = Field(
        "oenet",
        description="oenet: the thesis's Table 6.1 (vista's own method is direct alignment "
        "and needs no training).",
    )
    epochs: int = Field(OENET_EPOCHS, ge=1, le=10_000, description="Passes over the pairs.")
    batch: int = Field(256, ge=1, le=65_536, description="Pairs per step (thesis: 256).")
    learning_rate: float = Field(
        OENET_LEARNING_RATE, gt=0, le=10, description="SGD step (momentum 0.9)."
    )


TRAJECTORY = Output("trajectory", "trajectory.tum")
RUN_REPORT = Output("report", "odometry.json")
TRAJECTORY_PLOT = Output("plot", "trajectory.png")
EVALUATION = Output("report", "evaluation.json")
MODEL = Output("model", "oenet.onnx")
TRAINING_REPORT = Output("report", TRAINING_REPORT_NAME)

ODOMETRY = JobKind(
    name="odometry.run",
    aliases=("odometry",),
    queue="odometry",
    handler="services.odometry.jobs:odometry_job",
    shows=Presentation(
        page="services.odometry.views:run_view", scene="services.odometry.views:run_scene"
    ),
    params=OdometryParams,
    description=(
        "Floor-camera visual odometry of a `frames` sequence: the camera's trajectory (TUM, "
        "metres, in camera 0's frame), each pair's motion, confidence and flag with the "
        "position's growing 1σ, and a plot; with the archive's truth.tum, the evaluation "
        "(per-step RMSE, final error, ATE, drift) as `vista odometry eval` writes it."
    ),
    inputs=(
        SEQUENCE,
        Inputs(
            ("model",),
            "an OE-Net model (method oenet only)",
            min=0,
            needed_when=("method", ("oenet",)),
            only_when=("method", ("oenet",)),
            made_by=("odometry.train",),
        ),
    ),
    outputs=(TRAJECTORY, RUN_REPORT, TRAJECTORY_PLOT, EVALUATION),
)

ODOMETRY_TRAIN = JobKind(
    name="odometry.train",
    queue="training",
    handler="services.odometry.jobs:train_job",
    shows=TRAINING_PAGE,
    params=TrainParams,
    description=(
        "Trains OE-Net (thesis Table 6.1) on the consecutive frame pairs of `frames` "
        "sequences that carry their truth.tum, and writes it as an ONNX `model` (its "
        "metadata: architecture, training data, input, validation and test RMSE) with the "
        "training's history."
    ),
    inputs=(Inputs(("frames",), "frame sequences with their truth.tum", max=None),),
    outputs=(MODEL, TRAINING_REPORT),
)

KINDS = (ODOMETRY, ODOMETRY_TRAIN)
ARTIFACT_KINDS = (
    ArtifactKind(
        "frames",
        "A camera's frame sequence: a zip or tar of PNG frames in one folder with "
        "camera.json (size, fps, mm/px) and, when known, truth.tum.",
        "services.odometry.sequence:inspect_frames",
    ),
    ArtifactKind(
        "trajectory",
        "A camera trajectory in the TUM format (t tx ty tz qx qy qz qw).",
        "services.odometry.tum:inspect_trajectory",
    ),
)
"""The kinds of file only this service knows (the shared ones: ``services.lib.artifact_kinds``)."""

CLI = "services.odometry.cli:register"
"""Its commands: `vista odometry …` (``register(app, simulate_app, bench_app)``)."""
PRECOMPILE = "services.odometry.direct:warm_up"
"""What `vista precompile` runs to fill numba's cache: a PNG frame decoded, a pair aligned."""

SAMPLE_RUN = "services.odometry.sample:sample_run"
"""A run of its jobs on files it makes (``contract.samples``): `vista clients bench` draws their pages and scenes."""
