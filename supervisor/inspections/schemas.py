from __future__ import annotations

from dataclasses import asdict
from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, computed_field, field_validator

from contract.tolerances import Tolerances, limits_of
from supervisor.models.inspections import Area, InspectionStatus
from supervisor.requests import Millimetres, RequestModel, omittable

MatrixRow = Annotated[list[Millimetres], Field(min_length=4, max_length=4)]


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
    """Only the fields given change. `aircraft` and `serial` may be null (empty), and
    `tolerances` (no limits of its own: the defaults hold); the others may not."""

    title: str = omittable(min_length=1, max_length=200)
    aircraft: str | None = Field(None, max_length=100)
    serial: str | None = Field(None, max_length=100)
    area: Area = omittable()
    tolerances: StrictTolerances | None = None
    markers: list[ImageMarker] = omittable(max_length=16)
    status: InspectionStatus = omittable()


class InspectionOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    title: str
    aircraft: str
    serial: str
    area: Area
    tolerances: Tolerances
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
        return asdict(limits_of(self.tolerances))


class TrashedInspectionOut(InspectionOut):
    deleted_at: datetime
    deleted_by: int | None
