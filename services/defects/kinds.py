"""Job kind of the defects service (imported by the API: keep it light)."""

from pydantic import BaseModel, ConfigDict, Field

from contract.artifacts import ArtifactKind
from contract.kinds import Inputs, JobKind, Output, Presenter
from services.lib.artifact_kinds import FORMATS


class MeasureParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    pitch_mm: float = Field(2.0, ge=0.2, le=100, description="Distance between seam sections.")
    cell_mm: float = Field(
        0.2, ge=0.05, le=5, description="Height-map cell (raised for sparse clouds)."
    )
    max_gap_mm: float = Field(10.0, gt=0, le=100, description="Widest gap to look for.")
    keep_in_tolerance: bool = Field(
        True, description="Store seams within tolerance as `info` measurements too."
    )


RESULT = Output("report", "defects.json")
PROFILES = Output("plot", "seam-profiles.png")

MEASURE = JobKind(
    name="defects.measure",
    aliases=("measure",),
    queue="defects",
    handler="services.defects.jobs:measure_job",
    params=MeasureParams,
    description=(
        "Gap, step, parallelism and mismatch of every seam and junction, and dents, "
        "bumps, scratches and colour patches, in a stitched `cloud` artifact (from a "
        "`stitching.stitch` step or uploaded), judged against the inspection's tolerances. Writes the "
        "result (as `vista defects measure`'s RESULT.json), the seam profiles and one defect per "
        "finding out of tolerance (severity `info` for seams within it)."
    ),
    inputs=(Inputs(("cloud",), "the stitched point cloud"),),
    outputs=(RESULT, PROFILES),
    present=Presenter(RESULT, "services.defects.present:scene_lines"),
)

KINDS = (MEASURE,)
ARTIFACT_KINDS = (
    ArtifactKind(
        "mesh", "Nominal panel surfaces as a PLY triangle mesh.", f"{FORMATS}:inspect_mesh"
    ),
)
"""The kinds of file only this service knows (the shared ones: ``services.lib.artifact_kinds``)."""

CLI = "services.defects.cli:register"
"""Its commands: `vista defects …` (``register(app, simulate_app, bench_app)``)."""
DEMO_EXAMPLE = "services.defects.example:write_demo_assembly"
"""What `vista demo` simulates and runs: a cabin sidewall whose seams stray out of tolerance."""
