from __future__ import annotations

import re
from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field, field_validator

from contract.tolerances import ToleranceState
from supervisor.defects.schemas import Consensus, DefectType
from supervisor.judgments.schemas import JudgmentIn, JudgmentOut
from supervisor.requests import RequestId, RequestModel

MAX_BATCH = 1000

RFC3339 = re.compile(r"\d{4}-\d{2}-\d{2}[Tt]\d{2}:\d{2}:\d{2}(\.\d+)?([Zz]|[+-]\d{2}:\d{2})")
"""A JSON Schema `date-time`: lenient parsers read numbers and other forms as times too."""
ItemStatus = Literal["applied", "unchanged", "stale", "rejected"]


class SyncDefect(BaseModel):
    """A defect as a client keeps it: its value and tolerance in ``unit`` (``mm``, or
    ``delta_e`` for a colour patch), the other measurement details in ``measurements``.
    The lineage fields (``lineage_id`` … ``ended_run_id``) come only with a finding that a
    later measurement ended or that continues an earlier one; absent, they are null (its
    lineage is its own id)."""

    id: int
    run_id: int | None
    type: DefectType
    status: str
    severity: str
    tolerance_state: ToleranceState = Field(
        description="out, within or uncertain (within 2σ of its limit: see `measurements.advice`)."
    )
    value: float | None
    unit: str
    tolerance: float | None
    location_mm: list[float]
    normal: list[float]
    extent_mm: float
    confidence: float
    source: str
    measurements: dict
    created_at: datetime
    lineage_id: int | None = None
    supersedes_id: int | None = None
    superseded_by_id: int | None = Field(
        None, description="Set when a later measurement found it again: that finding."
    )
    ended: Literal["superseded", "not found again"] | None = Field(
        None,
        description="null while current. An ended finding is history: a client hides it "
        "(its judgments travel on with its successor); a verdict sent for it lands on its "
        "successor, or is refused when it was not found again.",
    )
    ended_run_id: int | None = None
    notes: list[dict] = Field(
        default_factory=list,
        description="What people noted about it (user_id, username, text, at), oldest "
        "first; absent when there is none.",
    )


class SyncConsensus(Consensus):
    defect_id: int


class JobSceneRef(BaseModel):
    job_id: int
    run_id: int
    kind: str
    step: str
    finished_at: str | None
    url: str = Field(description="Its glTF: `GET` it with the same token.")


class JobWarning(BaseModel):
    job_id: int
    run_id: int
    kind: str
    step: str
    warning: str = Field(description="What the job could not do, and why.")
    unmeasured_seams: int | None = Field(
        None, description="A measurement's seams left unmeasured (null: another kind)."
    )


class SyncOut(BaseModel):
    inspection: dict | None = Field(
        description="The inspection, when this page starts a full sync or it changed."
    )
    defects: list[SyncDefect] = Field(description="Defects created or changed (their state now).")
    judgments: list[JudgmentOut] = Field(description="Judgments created or changed.")
    consensus: list[SyncConsensus] = Field(
        description="The consensus of every defect whose judgments are in this page."
    )
    scene_etag: str = Field(description="The ETag of the inspection's scene.glb right now.")
    job_scenes: list[JobSceneRef] = Field(
        default_factory=list,
        description="The inspection's finished jobs with a 3D scene of their own (a "
        "trajectory, depth clouds, a track through a drive), newest first.",
    )
    warnings: list[JobWarning] = Field(
        default_factory=list,
        description="The inspection's succeeded jobs that could not do all they were asked "
        "(a measurement's unmeasured seams, and why), newest first: the inspection is not "
        "done while one is here.",
    )
    next_cursor: str = Field(description="Pass as `since` next time.")
    more: bool = Field(description="More is waiting: call again at once with next_cursor.")


class OfflineJudgment(JudgmentIn):
    """A judgment made on a headset, offline: the same fields as a PUT's, and which defect,
    when and under which client id."""

    client_id: str = Field(
        min_length=1, max_length=64, description="Made by the client (a UUID); retries reuse it."
    )
    defect_id: RequestId
    inspection_id: RequestId | None = Field(
        None,
        description="The inspection the client synced the defect from: the item is refused "
        "when the defect is not in it (send it; it keeps a verdict off another defect).",
    )
    client_time: datetime = Field(
        strict=False,  # read from a string, checked by _rfc3339 first
        description="When the user judged, by the client's clock, with its offset.",
    )

    @field_validator("client_time", mode="before")
    @classmethod
    def _rfc3339(cls, value: object) -> object:
        if not (isinstance(value, str) and RFC3339.fullmatch(value)):
            raise ValueError(
                "give an RFC 3339 date-time with a time zone, e.g. 2024-05-01T12:00:00Z"
            )
        return value


class JudgmentBatch(RequestModel):
    items: list[OfflineJudgment] = Field(min_length=1, max_length=MAX_BATCH)


class ItemResult(BaseModel):
    client_id: str
    defect_id: int
    status: ItemStatus = Field(
        description="applied: now your judgment; unchanged: the same as your judgment; stale: "
        "you judged this defect later (by client time) elsewhere; rejected: see detail (the "
        "defect is gone, in another inspection, or the judgment is not allowed)."
    )
    replayed: bool = Field(False, description="This client_id was sent before: first answer.")
    landed_on: int | None = Field(
        None,
        description="The finding your judgment landed on, when the one you sent it for was "
        "measured again since (its successor; `detail` says so). null: the one you sent.",
    )
    detail: str | None = None
    judgment: JudgmentOut | None = Field(None, description="Your judgment of the defect now.")


class BatchOut(BaseModel):
    results: list[ItemResult]
    consensus: list[SyncConsensus]
