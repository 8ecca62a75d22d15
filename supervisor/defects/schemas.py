from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field

from supervisor.ids import IdField
from supervisor.models.defects import DefectStatus, DefectType, Severity, Verdict
from supervisor.requests import MAX_MM, Millimetres, RequestModel

Vector3 = tuple[Millimetres, Millimetres, Millimetres]
"""A location (mm) or a direction (any length: the API normalises it), within ±1 km."""


class Consensus(BaseModel):
    """What reviewers think of a defect, from each user's current judgment."""

    counts: dict[Verdict, int]
    total: int
    majority: Verdict | None = Field(description="The verdict with strictly the most votes.")
    agreement: float = Field(description="Share of judgments that agree with the majority.")
    needs_review: bool = Field(
        description="Judgments are split: no strict majority, the majority is 'uncertain', "
        "or fewer than two thirds agree."
    )
    reclassified_as: dict[str, int] = Field(default_factory=dict)


class DefectCreate(RequestModel):
    """A finding reported by hand (jobs add theirs directly)."""

    inspection_id: IdField
    type: DefectType
    location_mm: Vector3
    normal: Vector3 = (0.0, 0.0, 1.0)
    value_mm: Millimetres | None = None
    tolerance_mm: Millimetres | None = None
    extent_mm: float = Field(0.0, ge=0, le=MAX_MM)
    severity: Severity = "minor"
    confidence: float = Field(1.0, ge=0, le=1)


class DefectUpdate(RequestModel):
    status: DefectStatus


class DefectOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    inspection_id: int
    run_id: int | None
    job_id: int | None
    type: DefectType
    status: DefectStatus
    value_mm: float | None
    tolerance_mm: float | None
    measurements: dict
    location_mm: list[float]
    normal: list[float]
    extent_mm: float
    severity: Severity
    confidence: float
    source: str
    created_at: datetime
    consensus: Consensus | None = None
