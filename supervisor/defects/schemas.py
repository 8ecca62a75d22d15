from __future__ import annotations

from datetime import datetime
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, computed_field

from contract.findings import stored_state
from contract.tolerances import ToleranceState
from contract.vocabulary import DefectType, Severity
from supervisor.models.defects import DefectStatus, Ended, Verdict
from supervisor.requests import MAX_MM, Millimetres, RequestId, RequestModel

Vector3 = Annotated[tuple[Millimetres, Millimetres, Millimetres], Field(strict=False)]
"""A location (mm) or a direction (any length: the API normalises it), within ±1 km. (A
JSON array: strict would want a Python tuple; its numbers stay strict.)"""


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

    inspection_id: RequestId = Field(description="An inspection that is not in the trash.")
    type: DefectType
    location_mm: Vector3
    normal: Vector3 = Field((0.0, 0.0, 1.0), description="Any length but zero.")
    value_mm: Millimetres | None = None
    tolerance_mm: Millimetres | None = None
    extent_mm: float = Field(0.0, ge=0, le=MAX_MM)
    severity: Severity = "minor"
    confidence: float = Field(1.0, ge=0, le=1)
    note: str = Field(
        "", max_length=2000, description="What you saw, kept as the finding's first note."
    )


class NoteIn(RequestModel):
    text: str = Field(min_length=1, max_length=2000, pattern=r"\S", description="The note.")


class DefectUpdate(RequestModel):
    status: DefectStatus
    reason: str = Field(
        "",
        max_length=2000,
        description="Why: required (not blank) to dismiss a defect that is not dismissed "
        "yet; kept with the defect and in the audit log.",
    )


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
    status_by: int | None = Field(None, description="Who last set the status.")
    status_reason: str = Field("", description="Why they did.")
    lineage_id: int | None = Field(
        None,
        description="The first finding of its line: every measurement of one physical "
        "defect shares it (see `GET /defects/{id}/history`).",
    )
    supersedes_id: int | None = Field(
        None, description="The earlier measurement's finding this one continues."
    )
    superseded_by_id: int | None = Field(
        None, description="The later measurement's finding that continues this one."
    )
    ended: Ended | None = Field(
        None,
        description="null while current; `superseded` (a later measurement found it again: "
        "see `superseded_by_id`) or `not found again` (a later measurement of its area did "
        "not find it).",
    )
    ended_run_id: int | None = Field(None, description="The run that ended it.")
    notes: list[dict] = Field(
        default_factory=list,
        description="What people noted about it, oldest first: user_id, username, text, at.",
    )
    created_at: datetime
    consensus: Consensus | None = None

    @computed_field(
        description="out (beyond its limit by 2σ or more), within (inside it by 2σ or "
        "more) or uncertain (within 2σ of it: `measurements.advice` says what would decide "
        "it); by the severity alone for a finding measured without a σ."
    )
    @property
    def tolerance_state(self) -> ToleranceState:
        return stored_state(self.severity, self.measurements)


class LineageStep(BaseModel):
    """One measurement's finding in a physical defect's line, oldest first."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    run_id: int | None
    run_name: str | None = None
    job_id: int | None
    type: DefectType
    status: DefectStatus
    severity: Severity
    value_mm: float | None
    measurements: dict
    created_at: datetime
    ended: Ended | None
    ended_run_id: int | None


class DefectHistoryOut(BaseModel):
    defect_id: int
    lineage_id: int
    current_id: int | None = Field(
        description="The line's current finding (null: its last measurement did not find it again)."
    )
    steps: list[LineageStep]
    judgments: list[dict] = Field(
        description="Every revision of every judgment made along the line, oldest first: "
        "user, verdict, new type, comment, revision, the run it was judged on."
    )
