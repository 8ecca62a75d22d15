"""Job kinds of the stitching service (imported by the API: keep it light)."""

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from contract.artifacts import ArtifactKind
from contract.kinds import Inputs, JobKind, Output
from services.lib.artifact_kinds import FORMATS

OpenCvMethod = Literal["tsai", "park", "horaud", "andreff", "daniilidis"]
"""OpenCV's ``calibrateHandEye`` methods."""
CalibrationMethod = Literal["vista", "thesis", OpenCvMethod]
IcpAlgorithm = Literal["bounded", "point-to-point", "point-to-plane"]
IcpMethod = Literal["none", IcpAlgorithm]
"""``none``: the kinematic poses only; else the ICP algorithm."""
IcpStart = Literal["kinematic", "none"]


class NoiseModel(BaseModel):
    """1σ per axis of the robot's reported flange pose and of the sensor's plate pose: what
    the vista calibration weighs each pair by, what a bounded ICP stitch lets a scan move
    within (the robot's, as HANDEYE.json records it) and what the simulators draw."""

    model_config = ConfigDict(extra="forbid")

    # A UR10e: its ±0.05 mm pose repeatability taken as σ per axis, and that 0.05 mm over
    # the ~600 mm of its wrist lever as the orientation's.
    robot_sigma_mm: float = Field(
        0.05, gt=0, le=10, description="Robot repeatability, 1σ per axis (mm)."
    )
    robot_sigma_deg: float = Field(
        0.005, gt=0, le=5, description="Robot orientation noise, 1σ per axis (deg)."
    )
    sensor_sigma_mm: float = Field(
        0.02, gt=0, le=10, description="Plate-pose noise of the sensor (mm)."
    )
    sensor_sigma_deg: float = Field(
        0.02, gt=0, le=5, description="Plate-pose noise of the sensor (deg)."
    )


class CalibrateParams(NoiseModel):
    method: CalibrationMethod = Field(
        "vista",
        description="vista (weighs each pair by the noise), the thesis's, or a classic solver.",
    )


class StitchParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    voxel_mm: float = Field(
        0.2, gt=0, le=10, description="Merge the points within one voxel of this edge (mm)."
    )
    loop_threshold: float = Field(0.8, gt=0, le=1, description="Drop points with a higher LoOP.")
    icp: IcpMethod = Field(
        "none",
        description="none (kinematic poses) | bounded (refine within the kinematic "
        "uncertainty) | point-to-point | point-to-plane (plain ICP, as the thesis tried).",
    )
    icp_start: IcpStart = Field(
        "kinematic",
        description="kinematic | none (no initial transform: the thesis's Fig. 6.4 b).",
    )


HANDEYE = Output("handeye", "handeye.json")
STITCHED_CLOUD = Output("cloud", "stitched.ply")
STITCH_REPORT = Output("report", "stitch-report.json")
OVERLAP_PLOT = Output("plot", "overlap.png")

CALIBRATE = JobKind(
    name="stitching.calibrate",
    aliases=("calibrate",),
    queue="stitching",
    handler="services.stitching.jobs:calibrate_job",
    params=CalibrateParams,
    description=(
        "Robot–sensor (hand-eye) calibration from the robot–plate pose pairs: writes the "
        "calibration (flange_T_sensor, base_T_target, the residual, dropped pairs and the "
        "uncertainty)."
    ),
    inputs=(Inputs(("pairs",), "the robot–plate pose pairs (JSON)"),),
    outputs=(HANDEYE,),
)

STITCH = JobKind(
    name="stitching.stitch",
    aliases=("stitch",),
    queue="stitching",
    handler="services.stitching.jobs:stitch_job",
    params=StitchParams,
    description=(
        "Kinematic stitching: the scan list names the PLY scans by artifact name, each with "
        "its robot pose; with the hand-eye calibration (uploaded or from a `stitching.calibrate` "
        "step) the scans are merged into one cleaned cloud, with the overlap quality report "
        "and histogram."
    ),
    inputs=(
        Inputs(("scans",), "the scan list with each scan's robot pose (JSON)"),
        Inputs(("scan",), "the PLY scans it names", max=None),
        Inputs(("handeye",), "the hand-eye calibration (uploaded or from stitching.calibrate)"),
    ),
    outputs=(STITCHED_CLOUD, STITCH_REPORT, OVERLAP_PLOT),
)

KINDS = (CALIBRATE, STITCH)
ARTIFACT_KINDS = (
    ArtifactKind(
        "pairs", "Robot–plate pose pairs for hand-eye calibration.", f"{FORMATS}:inspect_json"
    ),
    ArtifactKind(
        "scans", "The list of scans with each scan's robot pose.", f"{FORMATS}:inspect_json"
    ),
    ArtifactKind("handeye", "A hand-eye calibration (flange_T_sensor).", f"{FORMATS}:inspect_json"),
)
"""The kinds of file only this service knows (the shared ones: ``services.lib.artifact_kinds``)."""

CLI = "services.stitching.cli:register"
"""Its commands: `vista stitching …` (``register(app, simulate_app, bench_app)``)."""
