from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from supervisor.defects.schemas import DefectType


class Suggestion(BaseModel):
    action: Literal["keep", "raise", "lower"]
    tolerance: float = Field(description="The limit to use next time (the same one to keep).")
    reason: str


class ToleranceFeedback(BaseModel):
    """What reviewers made of the automatic findings judged against one limit."""

    type: DefectType
    bound: Literal["max", "min"] = Field(
        description="max: a value above the limit is a defect; min: below it (narrow gaps)."
    )
    tolerance: float
    unit: str
    flagged: int = Field(description="Automatic findings out of tolerance.")
    in_tolerance: int = Field(description="Automatic rows within tolerance kept for review.")
    reviewed: int = Field(description="Flagged findings whose reviewers reached a majority.")
    confirmed: int
    rejected: int
    reclassified: int
    uncertain: int = Field(description="Flagged findings judged, but with no firm majority.")
    confirmed_share: float | None = Field(description="confirmed / reviewed.")
    rejected_share: float | None = Field(description="rejected / reviewed.")
    missed: int = Field(description="Rows within tolerance that reviewers confirmed as defects.")
    suggestion: Suggestion


class FeedbackOut(BaseModel):
    inspection_id: int | None
    min_reviews: int
    groups: list[ToleranceFeedback]
    suggested_tolerances: dict | None = Field(
        description="The inspection's tolerances with every suggestion applied: ready to "
        "give to the next inspection (only with `inspection`)."
    )
