from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field

from supervisor.inspections.schemas import StrictTolerances, TolerancesPatch
from supervisor.requests import RequestId, RequestModel


class ToleranceSetCreate(RequestModel):
    name: str = Field(min_length=1, max_length=100, description="Unique, e.g. `A320 cabin lining`.")
    description: str = Field("", max_length=2000)
    tolerances: StrictTolerances


class ToleranceSetUpdate(RequestModel):
    """Only the fields given change; within `tolerances` only the limits named (null: that
    limit's default). A change of its limits makes a new version."""

    name: str | None = Field(None, min_length=1, max_length=100)
    description: str | None = Field(None, max_length=2000)
    tolerances: TolerancesPatch | None = None


class ToleranceSetOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    description: str
    tolerances: dict
    version: int = Field(description="Counts the changes of its limits, from 1.")
    created_by: int | None
    created_at: datetime
    updated_at: datetime


class ApplySet(RequestModel):
    set_id: RequestId = Field(description="The tolerance set whose limits the inspection takes.")


class ToleranceSchemaOut(BaseModel):
    """What a form needs to edit tolerances: the document's JSON Schema and every default."""

    json_schema: dict = Field(alias="schema")
    defaults: dict = Field(description="The limits that hold where the tolerances are silent.")

    model_config = ConfigDict(populate_by_name=True)
