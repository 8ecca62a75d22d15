from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field, model_validator

from supervisor.defects.schemas import Consensus, DefectType, Verdict
from supervisor.requests import RequestModel


class JudgmentIn(RequestModel):
    """`new_type` is given exactly when the verdict is `reclassified` (then it must differ
    from the defect's type)."""

    model_config = ConfigDict(
        json_schema_extra={
            "if": {"properties": {"verdict": {"const": "reclassified"}}},
            "then": {"required": ["new_type"], "properties": {"new_type": {"type": "string"}}},
            "else": {"properties": {"new_type": {"type": "null"}}},
        }
    )

    verdict: Verdict
    new_type: DefectType | None = Field(
        None, description="The type it really is: required when reclassified, else null."
    )
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
    judged_on_run_id: int | None = Field(
        None, description="The earlier run whose finding this was judged on (null: this one)."
    )


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
    judged_on_run_id: int | None = Field(
        None,
        description="Judged on run N's finding, an earlier measurement of this one (carried "
        "over when it was measured again); null: judged on this finding.",
    )
    history: list[JudgmentRevisionOut] | None = None


class MyJudgmentOut(BaseModel):
    judgment: JudgmentOut
    consensus: Consensus


class DefectJudgmentsOut(BaseModel):
    defect_id: int
    consensus: Consensus
    judgments: list[JudgmentOut]
