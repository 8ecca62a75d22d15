from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, computed_field

from supervisor.models.jobs import JobStatus
from supervisor.requests import RequestId, RequestModel

STEP_NAME_PATTERN = r"^[a-z][a-z0-9_-]{0,63}$"


class StepIn(RequestModel):
    name: str = Field(pattern=STEP_NAME_PATTERN, description="Unique within the run.")
    kind: str = Field(min_length=1, max_length=64, description="A job kind from GET /job-kinds.")
    params: dict[str, Any] = Field(default_factory=dict)
    inputs: list[RequestId] = Field(
        default_factory=list, max_length=1000, description="Artifact ids of this inspection."
    )
    after: list[str] = Field(
        default_factory=list,
        max_length=100,
        description="Earlier steps that must succeed first; their outputs become inputs.",
    )


class RunCreate(RequestModel):
    name: str = Field("", max_length=200)
    steps: list[StepIn] = Field(min_length=1, max_length=100)


class JobOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    run_id: int
    inspection_id: int
    step: str
    position: int
    kind: str
    queue: str
    params: dict
    input_artifact_ids: list[int]
    depends_on: list[int] = Field(default_factory=list)
    status: JobStatus
    progress: float
    message: str
    attempts: int
    max_attempts: int
    error: str | None
    result: dict | None
    cancel_requested: bool
    worker: str | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    heartbeat_at: datetime | None

    @computed_field(
        description="What a succeeded job could not do and a person must know (e.g. seams "
        "a measurement left unmeasured, and why): its result's `warning`; null when none."
    )
    @property
    def warning(self) -> str | None:
        warning = (self.result or {}).get("warning") if self.status == "succeeded" else None
        return warning if isinstance(warning, str) else None


class RunOut(BaseModel):
    id: int
    inspection_id: int
    name: str
    status: JobStatus
    progress: float
    created_by: int | None
    created_at: datetime
    jobs: list[JobOut]

    @computed_field(description="Its jobs' warnings, one a line; null when none.")
    @property
    def warning(self) -> str | None:
        warnings = [f"{job.step}: {job.warning}" for job in self.jobs if job.warning]
        return "\n".join(warnings) or None


class InputsOut(BaseModel):
    kinds: list[str]
    what: str
    min: int
    max: int | None = Field(description="None: no upper limit.")
    needed_when: tuple[str, list[str]] | None = Field(
        None, description="(parameter, values): with the parameter at one of them, at least one."
    )
    only_when: tuple[str, list[str]] | None = Field(
        None, description="(parameter, values): with the parameter at any other value, none."
    )


class OutputOut(BaseModel):
    kind: str
    name: str = Field(description="File name; `{stem}` is the input's name without suffix.")
    per_input: bool


class JobKindOut(BaseModel):
    name: str
    aliases: list[str] = Field(
        description="Older names a step may still give; its job is stored under `name`."
    )
    queue: str
    description: str
    input_kinds: list[str]
    inputs: list[InputsOut] = Field(
        description="What a step reads, from its `inputs` and the outputs of its `after` "
        "steps; checked when the run is created."
    )
    outputs: list[OutputOut]
    params_schema: dict
