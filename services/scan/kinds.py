"""Job kinds of the scan service (imported by the API: keep it light)."""

from pydantic import BaseModel, ConfigDict, Field

from contract.artifacts import ArtifactKind
from contract.kinds import Inputs, JobKind, Output
from services.lib.artifact_kinds import FORMATS


class ScanInspectParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    preview_points: int = Field(
        100_000, ge=1_000, le=5_000_000, description="Point budget of the decimated preview."
    )
    spacing_sample: int = Field(
        20_000, ge=100, le=1_000_000, description="Points sampled to estimate the spacing."
    )


REPORT = Output("report", "{stem}-report.json", per_input=True)
PREVIEW = Output("preview", "{stem}-preview.ply", per_input=True)

SCAN_INSPECT = JobKind(
    name="scan.inspect",
    queue="scan",
    handler="services.scan.jobs:inspect_scan",
    params=ScanInspectParams,
    description=(
        "Checks a PLY point cloud and reports point count, bounds, spacing, density and "
        "finiteness (a JSON `report` artifact) and writes a decimated `preview` PLY."
    ),
    inputs=(Inputs(("scan", "cloud"), "PLY point clouds", max=None),),
    outputs=(REPORT, PREVIEW),
)

KINDS = (SCAN_INSPECT,)
ARTIFACT_KINDS = (
    ArtifactKind(
        "scan", "One scan as the sensor took it, sensor frame, mm.", f"{FORMATS}:inspect_cloud"
    ),
    ArtifactKind("preview", "A decimated copy of a cloud for viewers.", f"{FORMATS}:inspect_cloud"),
)
"""The kinds of file only this service knows (the shared ones: ``services.lib.artifact_kinds``)."""
CLI = "services.scan.cli:register"
