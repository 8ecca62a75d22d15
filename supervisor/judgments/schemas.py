from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field, model_validator

from supervisor.defects.schemas import Consensus, DefectType, Verdict
from supervisor.requests import RequestModel


class JudgmentIn(RequestModel):
    verdict: Verdict
    new_type: DefectType | None = Field(None, description="Required when reclassified.")
    comment: str = Field("", max_length=4000)

    @model_validator(mode="after")
    def _new_type_only_when_reclassified(self) -> JudgmentIn:
        if self.verdict == "reclassified" and self.new_type is None:
            raise ValueError("new_type is required when the verdict is 'reclassified'")
        if self.verdict != "reclassified" and self.new_type is not None:
            raise ValueError("new_type is only given when the verdict is 'reclassified'")
        return self


class JudgmentRevisionOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    revision: int
    verdict: Verdict
    new_type: DefectType | None
    comment: str
    created_at: datetime


class JudgmentOut(BaseModel):
    defect_id: int
    user_id: int
    username: str
    verdict: Verdict
    new_type: DefectType | None
    comment: str
    revision: int
    updated_at: datetime
    client_time: datetime | None = Field(
        None, description="When it was made by the judging client's clock (last one wins)."
    )
    history: list[JudgmentRevisionOut] | None = None


class MyJudgmentOut(BaseModel):
    judgment: JudgmentOut
    consensus: Consensus


class DefectJudgmentsOut(BaseModel):
    defect_id: int
    consensus: Consensus
    judgments: list[JudgmentOut]
