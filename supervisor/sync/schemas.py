from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field, field_validator

from supervisor.defects.schemas import Consensus, DefectType
from supervisor.ids import IdField
from supervisor.judgments.schemas import JudgmentIn, JudgmentOut
from supervisor.requests import RequestModel

MAX_BATCH = 1000

ItemStatus = Literal["applied", "unchanged", "stale", "rejected"]


class SyncDefect(BaseModel):
    """A defect as a client keeps it: its value and tolerance in ``unit`` (``mm``, or
    ``delta_e`` for a colour patch), the other measurement details in ``measurements``."""

    id: int
    run_id: int | None
    type: DefectType
    status: str
    severity: str
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


class SyncConsensus(Consensus):
    defect_id: int


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
    next_cursor: str = Field(description="Pass as `since` next time.")
    more: bool = Field(description="More is waiting: call again at once with next_cursor.")


class OfflineJudgment(JudgmentIn):
    """A judgment made on a headset, offline: the same fields as a PUT's, and which defect,
    when and under which client id."""

    client_id: str = Field(
        min_length=1, max_length=64, description="Made by the client (a UUID); retries reuse it."
    )
    defect_id: IdField
    client_time: datetime = Field(description="When the user judged, by the client's clock.")

    @field_validator("client_time")
    @classmethod
    def _aware(cls, value: datetime) -> datetime:
        if value.tzinfo is None:
            raise ValueError("give a time zone (e.g. a trailing 'Z' for UTC)")
        return value


class JudgmentBatch(RequestModel):
    items: list[OfflineJudgment] = Field(min_length=1, max_length=MAX_BATCH)


class ItemResult(BaseModel):
    client_id: str
    defect_id: int
    status: ItemStatus = Field(
        description="applied: now your judgment; unchanged: the same as your judgment; stale: "
        "you judged this defect later (by client time) elsewhere; rejected: see detail."
    )
    replayed: bool = Field(False, description="This client_id was sent before: first answer.")
    detail: str | None = None
    judgment: JudgmentOut | None = Field(None, description="Your judgment of the defect now.")


class BatchOut(BaseModel):
    results: list[ItemResult]
    consensus: list[SyncConsensus]
