from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Area = Literal["cargo", "cabin", "component"]
InspectionStatus = Literal["planned", "scanning", "processing", "review", "closed"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class RangeMm(_Strict):
    min: float | None = Field(None, ge=0)
    max: float | None = Field(None, ge=0)


class LimitMm(_Strict):
    max: float = Field(gt=0)


class SurfaceTolerances(_Strict):
    dent_depth_mm: float | None = Field(None, gt=0, description="Deepest acceptable dent/bump.")
    scratch_depth_mm: float | None = Field(None, gt=0, description="Deepest acceptable scratch.")
    color_delta_e: float | None = Field(None, gt=0, description="Largest acceptable CIE ΔE.")


class Tolerances(_Strict):
    """Acceptance limits; a measurement outside them becomes a defect."""

    gap_mm: RangeMm | None = None
    step_mm: LimitMm | None = None
    parallelism_mm: LimitMm | None = None
    mismatch_mm: LimitMm | None = None
    surface: SurfaceTolerances | None = None


class InspectionCreate(_Strict):
    title: str = Field(min_length=1, max_length=200)
    aircraft: str = Field("", max_length=100)
    serial: str = Field("", max_length=100)
    area: Area
    tolerances: Tolerances = Field(default_factory=Tolerances)
    status: InspectionStatus = "planned"


class InspectionUpdate(_Strict):
    title: str | None = Field(None, min_length=1, max_length=200)
    aircraft: str | None = Field(None, max_length=100)
    serial: str | None = Field(None, max_length=100)
    area: Area | None = None
    tolerances: Tolerances | None = None
    status: InspectionStatus | None = None


class InspectionOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    title: str
    aircraft: str
    serial: str
    area: Area
    tolerances: Tolerances
    status: InspectionStatus
    created_by: int | None
    created_at: datetime
    updated_at: datetime
