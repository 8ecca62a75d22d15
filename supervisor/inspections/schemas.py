from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from services.defects.tolerances import Tolerances
from supervisor.models.inspections import Area, InspectionStatus
from supervisor.requests import Millimetres, RequestModel


class ImageMarker(RequestModel):
    """A printed image marker at a known pose: a headset that sees it aligns the scene."""

    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    area: Literal["cargo", "cabin"]
    base_T_marker: list[list[Millimetres]] = Field(
        description="4 × 4 row-major rigid transform, mm: the marker's frame (x right, y up "
        "the image, z out of it) in the base frame."
    )
    size_mm: float = Field(gt=0, le=10_000, description="Printed edge length of the image.")
    image: str = Field("", max_length=200, description="The target's name in the AR library.")

    @field_validator("base_T_marker")
    @classmethod
    def _rigid(cls, value: list[list[float]]) -> list[list[float]]:
        if len(value) != 4 or any(len(row) != 4 for row in value):
            raise ValueError("must be 4 × 4")
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
    tolerances: Tolerances = Field(default_factory=Tolerances)
    markers: list[ImageMarker] = Field(default_factory=list, max_length=16)
    status: InspectionStatus = "planned"


class InspectionUpdate(RequestModel):
    title: str | None = Field(None, min_length=1, max_length=200)
    aircraft: str | None = Field(None, max_length=100)
    serial: str | None = Field(None, max_length=100)
    area: Area | None = None
    tolerances: Tolerances | None = None
    markers: list[ImageMarker] | None = Field(None, max_length=16)
    status: InspectionStatus | None = None


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
