"""Job kinds of the scan service (imported by the API: keep it light)."""

from pydantic import BaseModel, ConfigDict, Field

from contract.kinds import Inputs, JobKind, Output


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
