from __future__ import annotations

from dataclasses import asdict
from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, computed_field, field_validator

from contract.tolerances import TOLERANCE_MAX_MM, Tolerances, limits_of
from supervisor.models.inspections import InspectionStatus
from supervisor.requests import Millimetres, RequestModel, omittable

MatrixRow = Annotated[list[Millimetres], Field(min_length=4, max_length=4)]
Area = Annotated[
    str,
    Field(
        min_length=1,
        max_length=64,
        pattern=r"\S",
        description="What is inspected, in your words: `cabin`, `cargo`, `wing flap 3`, "
        "`street drive 0048` (`GET /areas` suggests those in use).",
    ),
]


def _strictly(value: Any) -> Any:
    """Tolerances as strict as a request body (their model is shared with CONFIG.json)."""
    return Tolerances.model_validate(value, strict=True) if isinstance(value, dict) else value


StrictTolerances = Annotated[
    Tolerances,
    BeforeValidator(_strictly),
    Field(
        description="Acceptance limits, mm (colour: ΔE); a limit not given takes its default. "
        "`gap_mm.min` must be below `gap_mm.max` (defaults 0.5 and 3.0 for a side not given)."
    ),
]


class RangePatch(RequestModel):
    """A gap's range, changed: a side not named keeps its value, null restores its default."""

    min: float | None = Field(None, ge=0, le=TOLERANCE_MAX_MM)
    max: float | None = Field(None, gt=0, le=TOLERANCE_MAX_MM)


class LimitPatch(RequestModel):
    max: float | None = Field(None, gt=0, le=TOLERANCE_MAX_MM)


class SurfacePatch(RequestModel):
    dent_depth_mm: float | None = Field(None, gt=0, le=TOLERANCE_MAX_MM)
    scratch_depth_mm: float | None = Field(None, gt=0, le=TOLERANCE_MAX_MM)
    color_delta_e: float | None = Field(None, gt=0, le=100)


class ProfileBandPatch(RequestModel):
    min: float | None = Field(None, ge=-TOLERANCE_MAX_MM, le=0)
    max: float = Field(..., ge=0, le=TOLERANCE_MAX_MM)


class ProfilePatch(RequestModel):
    """A surface-profile band changed: `max` alone is ±max; `regions` replaces every
    region's own band at once (null: none)."""

    min: float | None = Field(None, ge=-TOLERANCE_MAX_MM, le=0)
    max: float | None = Field(None, ge=0, le=TOLERANCE_MAX_MM)
    regions: dict[str, ProfileBandPatch] | None = None


class TolerancesPatch(RequestModel):
    """Changes to an inspection's tolerances: a limit (or section) not named keeps its
    value, one given takes it, one given as null goes back to its default. The merged
    limits must hold together (422): a gap's `min` below its `max`."""

    gap_mm: RangePatch | None = None
    step_mm: LimitPatch | None = None
    parallelism_mm: LimitPatch | None = None
    mismatch_mm: LimitPatch | None = None
    surface: SurfacePatch | None = None
    profile_mm: ProfilePatch | None = None

    def changes(self) -> dict:
        """What was sent: sections and limits named, null where a default is restored."""
        return self.model_dump(mode="json", exclude_unset=True)


class ImageMarker(RequestModel):
    """A printed image marker at a known pose: a headset that sees it aligns the scene."""

    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    area: Literal["cargo", "cabin"]
    base_T_marker: list[MatrixRow] = Field(
        min_length=4,
        max_length=4,
        description="4 × 4 row-major rigid transform, mm: the marker's frame (x right, y up "
        "the image, z out of it) in the base frame. Rigid: the last row is 0 0 0 1 and the "
        "rotation part orthonormal, not mirroring (determinant +1).",
    )
    size_mm: float = Field(gt=0, le=10_000, description="Printed edge length of the image.")
    image: str = Field("", max_length=200, description="The target's name in the AR library.")

    @field_validator("base_T_marker")
    @classmethod
    def _rigid(cls, value: list[list[float]]) -> list[list[float]]:
        if value[3] != [0.0, 0.0, 0.0, 1.0]:
            raise ValueError("the last row must be 0 0 0 1")
        rotation = [row[:3] for row in value[:3]]
        for i in range(3):
            for j in range(3):
                dot = sum(rotation[k][i] * rotation[k][j] for k in range(3))
                if abs(dot - (1.0 if i == j else 0.0)) > 1e-6:
                    raise ValueError("the rotation part must be orthonormal")
        r = rotation
        det = (
            r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
            - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0])
        )
        if det < 0:
            raise ValueError("the rotation part must not mirror (determinant −1)")
        return value


class InspectionCreate(RequestModel):
    title: str = Field(min_length=1, max_length=200)
    aircraft: str = Field("", max_length=100)
    serial: str = Field("", max_length=100)
    area: Area
    tolerances: StrictTolerances = Field(default_factory=Tolerances)
    markers: list[ImageMarker] = Field(default_factory=list, max_length=16)
    status: InspectionStatus = "planned"


class InspectionUpdate(RequestModel):
    """Only the fields given change. `aircraft` and `serial` may be null (empty). Within
    `tolerances` only the limits named change (null: that limit's default); `tolerances`
    null restores every default. The others may not be null."""

    title: str = omittable(min_length=1, max_length=200)
    aircraft: str | None = Field(None, max_length=100)
    serial: str | None = Field(None, max_length=100)
    area: Area = omittable()
    tolerances: TolerancesPatch | None = None
    markers: list[ImageMarker] = omittable(max_length=16)
    status: InspectionStatus = omittable()


class AppliedSet(BaseModel):
    id: int
    name: str
    version: int
    edited: bool = False


class InspectionOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    title: str
    aircraft: str
    serial: str
    area: Area
    tolerances: Tolerances
    tolerance_set: AppliedSet | None = Field(
        None,
        description="The named tolerance set last applied (its name and version then; "
        "`edited`: a limit was changed by hand since).",
    )
    markers: list[ImageMarker]
    status: InspectionStatus
    created_by: int | None
    created_at: datetime
    updated_at: datetime

    @computed_field(
        description="Every limit the findings are judged by: the tolerances' own and the "
        "defaults where they are silent (mm; colour in ΔE)."
    )
    @property
    def limits(self) -> dict[str, float]:
        # a region's own profile band is read from `tolerances.profile_mm.regions`
        flat = asdict(limits_of(self.tolerances))
        del flat["profile_regions"]
        return flat


class TrashedInspectionOut(InspectionOut):
    deleted_at: datetime
    deleted_by: int | None
