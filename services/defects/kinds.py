"""Job kinds of the defects service (imported by the API: keep it light)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from contract.artifacts import ArtifactKind
from contract.kinds import Inputs, JobKind, Output, Presentation, Presenter
from services.lib.artifact_kinds import FORMATS

EdgeModel = Literal["auto", "square", "chamfer", "round", "free", "void"]
GapMode = Literal["walls", "surface", "distance", "sharp"]


class MeasureSettings(BaseModel):
    """How a measurement is taken: the `measurement` block of CONFIG.json and the measure
    job's parameters alike (the algorithm's configs take their defaults from here)."""

    model_config = ConfigDict(extra="forbid")

    pitch_mm: float = Field(2.0, ge=0.2, le=100, description="Distance between seam sections.")
    cell_mm: float = Field(
        0.2, ge=0.05, le=5, description="Height-map cell (raised for sparse clouds)."
    )
    max_gap_mm: float = Field(10.0, gt=0, le=100, description="Widest gap to look for.")
    min_seam_length_mm: float = Field(
        20.0, gt=0, le=10_000, description="Shorter shared borders are not seams."
    )
    min_panel_area_mm2: float = Field(
        1000.0, gt=0, le=1e8, description="Smaller surfaces are not panels."
    )
    slab_mm: float = Field(1.0, gt=0, le=50, description="Thickness of a seam section.")
    edge_band_mm: float = Field(
        2.5, gt=0, le=50, description="A panel's top is fitted from this far inside its end."
    )
    top_band_mm: float = Field(6.0, gt=0, le=100, description="Width of the top fitted.")
    max_view_deg: float = Field(
        30.0,
        gt=0,
        lt=90,
        description="How far off the normal a view may have been (a lower corner closer to "
        "the higher panel's edge than step × tan(this) may be in its shadow).",
    )
    edge_model: EdgeModel = Field(
        "auto",
        description="auto: each side's edge model by the information criterion; square, "
        "chamfer, round, free: that model on every side; void: the last measured point "
        "(what a single-profile gap gauge reports).",
    )
    gap_mode: GapMode = Field(
        "walls",
        description="walls: between the side faces along the tops' mean direction; surface: "
        "between the edge points along panel a's top; distance: straight between the edge "
        "points; sharp: straight between the virtual sharp edges.",
    )


class MeasureParams(MeasureSettings):
    keep_in_tolerance: bool = Field(
        True, description="Store seams within tolerance as `info` measurements too."
    )


AlignMethod = Literal["given", "best-fit", "points"]
Point = tuple[float, float, float]


class ReferencePoints(BaseModel):
    """Named points of the nominal and the same points picked on the scan (mm), for a
    3-2-1 / RPS alignment."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    nominal: dict[str, Point] = Field(..., min_length=3, description="On the nominal.")
    scan: dict[str, Point] = Field(..., min_length=3, description="Picked on the scan.")


class CompareParams(BaseModel):
    """How a scan is compared with its nominal (the tolerances: the inspection's, with
    ``profile_mm``)."""

    model_config = ConfigDict(extra="forbid")

    align: AlignMethod = Field(
        "best-fit",
        description="given: the cloud is in the part's frame already; best-fit: robust "
        "point-to-plane ICP onto the nominal; points: reference points (3-2-1 / RPS).",
    )
    start: Literal["as-is", "principal-axes"] = Field(
        "as-is",
        description="Where a best fit starts: the cloud as it lies (a robot cell's or a "
        "fixture's rough pose), or its principal axes matched to the nominal's (a cloud "
        "in a scanner's own frame; a nearly symmetric part is then ambiguous).",
    )
    reference_points: ReferencePoints | None = Field(
        None, description="For align=points: the named points on the nominal and the scan."
    )
    color_scale_mm: float | None = Field(
        None,
        gt=0,
        le=100,
        description="Half-width of the deviation colour bar (default: the profile band's "
        "wider side).",
    )

    @model_validator(mode="after")
    def _points_given(self) -> CompareParams:
        if self.align == "points" and self.reference_points is None:
            raise ValueError("align=points needs reference_points")
        return self


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
    inputs=(Inputs(("cloud",), "the stitched point cloud", made_by=("stitching.stitch",)),),
    outputs=(RESULT, PROFILES),
    shows=Presentation(
        page="services.defects.views:measure_view",
        scene="services.defects.views:measure_scene",
        inspection=Presenter(RESULT, "services.defects.present:scene_lines", surfaces=("mesh",)),
    ),
)

COMPARISON = Output("report", "comparison.json")
DEVIATION_CLOUD = Output("cloud", "deviation.ply")
HISTOGRAM = Output("plot", "deviation-histogram.png")

COMPARE = JobKind(
    name="defects.compare",
    queue="defects",
    handler="services.defects.jobs:compare_job",
    params=CompareParams,
    description=(
        "A scan against its part's nominal (CAD): the `cloud` aligned to the `nominal` "
        "(given, best fit or reference points, with its residual and pose σ), each point's "
        "signed deviation, per region its statistics and coverage, and every area beyond "
        "the inspection's profile band (`profile_mm`) a `deviation` finding. Writes the "
        "result (as `vista defects compare`'s RESULT.json), the aligned cloud coloured "
        "by deviation (with the deviation as a scalar field) and the histogram."
    ),
    inputs=(
        Inputs(("cloud",), "the scan", made_by=("stitching.stitch",)),
        Inputs(("nominal",), "the part's nominal model"),
    ),
    outputs=(COMPARISON, DEVIATION_CLOUD, HISTOGRAM),
    shows=Presentation(
        page="services.defects.views:compare_view",
        scene="services.defects.views:compare_scene",
        inspection=Presenter(
            COMPARISON,
            "services.defects.present:no_lines",
            surfaces=("nominal",),
            points=DEVIATION_CLOUD,
        ),
    ),
)

KINDS = (MEASURE, COMPARE)
ARTIFACT_KINDS = (
    ArtifactKind(
        "mesh", "Nominal panel surfaces as a PLY triangle mesh.", f"{FORMATS}:inspect_mesh"
    ),
    ArtifactKind(
        "nominal",
        "A part's nominal (CAD) model: STL (binary or ASCII), OBJ, PLY mesh, glTF/GLB or "
        "STEP (tessellated to 0.01 mm), in mm unless the file says otherwise (glTF: metres) "
        "or `units` does; its regions (STL solids, OBJ groups, glTF meshes, STEP faces) "
        "kept; whether it is closed and consistently oriented is reported, not required.",
        f"{FORMATS}:inspect_nominal",
    ),
)
"""The kinds of file only this service knows (the shared ones: ``services.lib.artifact_kinds``)."""

CLI = "services.defects.cli:register"
"""Its commands: `vista defects …` (``register(app, simulate_app, bench_app)``)."""
DEMO_EXAMPLE = "services.defects.example:write_demo_assembly"
"""What `vista demo` simulates and runs: a cabin sidewall whose seams stray out of tolerance."""
PRECOMPILE = "services.defects.measure:warm_up"
"""What `vista precompile` runs to fill numba's cache: a small measurement and comparison."""
USES = ("stitching",)
"""The services whose code this one calls (its simulator writes a stitching session and
merges the scans by ``services.stitching.stitch``, as a real inspection does): a service
reaches another only when it names it here (``tests/test_layout.py``)."""
