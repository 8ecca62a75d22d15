"""A job kind for exercising the engine itself: it sleeps, reports progress, can fail.

Loaded only through ``VISTA_EXTRA_JOB_KINDS=tests.jobkinds`` by the tests.
"""

from __future__ import annotations

import time

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from contract.context import JobContext
from contract.errors import TransientJobError
from contract.kinds import ANY_KIND, Inputs, JobKind, Output


class SleepParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    seconds: float = Field(0.2, ge=0, le=120)
    transient_failures: int = Field(
        0, ge=0, le=10, description="Attempts that fail transiently first."
    )
    fail_with: str | None = Field(None, description="Fail permanently with this message.")
    allocate_mb: int = Field(0, ge=0, le=1 << 20, description="Allocate (and touch) this much.")


def sleep_job(ctx: JobContext) -> dict:
    params = ctx.params
    if params.allocate_mb:
        np.ones(params.allocate_mb << 17)  # float64: 8 bytes each
    steps = max(1, int(params.seconds / 0.05))
    for step in range(steps):
        ctx.progress(step / steps, f"step {step} of {steps}")
        time.sleep(params.seconds / steps)
    if ctx.attempt <= params.transient_failures:
        raise TransientJobError(f"simulated outage in attempt {ctx.attempt}")
    if params.fail_with:
        raise ValueError(params.fail_with)
    inputs = sorted(a.id for a in ctx.inputs)
    ctx.add_artifact_json({"attempt": ctx.attempt, "inputs": inputs}, kind="echo", name="echo.json")
    return {"attempt": ctx.attempt, "inputs": inputs}


SLEEP = JobKind(
    name="test.sleep",
    queue="test",
    handler="tests.jobkinds:sleep_job",
    params=SleepParams,
    description="Test only: sleeps with progress, then succeeds or fails as asked.",
    inputs=(Inputs((ANY_KIND,), "any artifacts", min=0, max=None),),
    outputs=(Output("echo", "echo.json"),),
)

KINDS = (SLEEP,)
