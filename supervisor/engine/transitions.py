"""Ending a job's running attempt: the one place its status changes after it was claimed.

A guarded UPDATE (the job is still running in this very attempt, so a worker presumed
dead cannot overwrite its successor), the change-log row, and what follows from the new
status: dependents promoted or cancelled, the inspection's status brought along.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import ColumnElement, select, update
from sqlalchemy.orm import Session

from supervisor.changes import record_change
from supervisor.engine.dispatch import Dispatch
from supervisor.engine.graph import cancel_dependents, promote_dependents
from supervisor.engine.port import JobRecords
from supervisor.models import Job


def end_attempt(
    session: Session,
    job_id: int,
    attempt: int,
    *,
    records: JobRecords,
    status: str,
    guard: tuple[ColumnElement[bool], ...] = (),
    **values: Any,  # the job's other columns to set
) -> list[Dispatch] | None:
    """Move attempt ``attempt`` of job ``job_id`` from running to ``status`` (queued again,
    succeeded, failed or cancelled), setting ``values``; ``guard``: further conditions.
    Returns the jobs that became ready, or None when the attempt was no longer the job's
    running one and nothing changed."""
    changed = session.execute(
        update(Job)
        .where(Job.id == job_id, Job.status == "running", Job.attempts == attempt, *guard)
        .values(status=status, **values)
    ).rowcount
    if not changed:
        return None
    step, inspection_id = session.execute(
        select(Job.step, Job.inspection_id).where(Job.id == job_id)
    ).one()
    ready = []
    if status == "succeeded":
        ready = promote_dependents(session, job_id)
    elif status in ("failed", "cancelled"):
        cancel_dependents(session, job_id, f"not run: step '{step}' (job {job_id}) {status}")
    records.job_ended(session, inspection_id=inspection_id)
    record_change(session, entity="job", entity_id=job_id, op="update", inspection_id=inspection_id)
    return ready
