"""Job kinds of the stitching service (imported by the API: keep it light)."""

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from supervisor.engine.registry import Inputs, JobKind, Output, register

CalibrationMethod = Literal["vista", "thesis", "tsai", "park", "horaud", "andreff", "daniilidis"]
IcpMethod = Literal["none", "bounded", "point-to-point", "point-to-plane"]


class CalibrateParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    method: CalibrationMethod = "vista"
    robot_sigma_mm: float = Field(0.05, gt=0, le=10, description="Robot repeatability, 1σ/axis.")
    robot_sigma_deg: float = Field(0.005, gt=0, le=5, description="Robot orientation noise.")
    sensor_sigma_mm: float = Field(0.02, gt=0, le=10, description="Plate-pose noise (mm).")
    sensor_sigma_deg: float = Field(0.02, gt=0, le=5, description="Plate-pose noise (deg).")


class StitchParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    voxel_mm: float = Field(0.2, gt=0, le=10, description="Closest-vertex merge voxel edge.")
    loop_threshold: float = Field(0.8, gt=0, le=1, description="Drop points with a higher LoOP.")
    icp: IcpMethod = Field("none", description="Refine the kinematic poses by ICP.")
    icp_start: Literal["kinematic", "none"] = "kinematic"


CALIBRATE = register(
    JobKind(
        name="calibrate",
        queue="stitching",
        handler="services.stitching.jobs:calibrate_job",
        params=CalibrateParams,
        description=(
            "Robot–sensor (hand-eye) calibration from a pairs JSON artifact (kind `pairs`): "
            "writes handeye.json (kind `handeye`) with flange_T_sensor, base_T_target, the "
            "residual, dropped pairs and the uncertainty."
        ),
        inputs=(Inputs(("pairs",), "the robot–plate pose pairs (JSON)"),),
        outputs=(Output("handeye", "handeye.json"),),
    )
)

STITCH = register(
    JobKind(
        name="stitch",
        queue="stitching",
        handler="services.stitching.jobs:stitch_job",
        params=StitchParams,
        description=(
            "Kinematic stitching: a scans JSON artifact (kind `scans`) naming PLY artifacts "
            "(kind `scan`) by name, and a `handeye` artifact (uploaded or from a `calibrate` "
            "step). Writes the cleaned, merged stitched.ply (kind `cloud`), stitch-report.json "
            "(kind `report`) and the overlap histogram overlap.png (kind `plot`)."
        ),
        inputs=(
            Inputs(("scans",), "the scan list with each scan's robot pose (JSON)"),
            Inputs(("scan",), "the PLY scans it names", max=None),
            Inputs(("handeye",), "the hand-eye calibration (uploaded or from `calibrate`)"),
        ),
        outputs=(
            Output("cloud", "stitched.ply"),
            Output("report", "stitch-report.json"),
            Output("plot", "overlap.png"),
        ),
    )
)
