"""A run's dependency graph: which jobs wait for which, promoting and cancelling along it."""

from __future__ import annotations

from collections import defaultdict

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from supervisor.changes import record_update
from supervisor.engine.dispatch import Dispatch
from supervisor.models import Job, JobDependency
from supervisor.models._types import utcnow
from supervisor.models.jobs import NOT_STARTED


def dependencies(session: Session, job_ids: list[int]) -> dict[int, list[int]]:
    """The jobs each of ``job_ids`` waits for."""
    edges: dict[int, list[int]] = defaultdict(list)
    for job_id, depends_on_id in session.execute(
        select(JobDependency.job_id, JobDependency.depends_on_id)
        .where(JobDependency.job_id.in_(job_ids))
        .order_by(JobDependency.depends_on_id)
    ):
        edges[job_id].append(depends_on_id)
    return edges


def dependents(session: Session, job_ids: list[int]) -> list[int]:
    """The jobs that wait for any of ``job_ids``."""
    return list(
        session.scalars(
            select(JobDependency.job_id).where(JobDependency.depends_on_id.in_(job_ids))
        )
    )


def promote_dependents(session: Session, job_id: int) -> list[Dispatch]:
    """Queue the waiting jobs whose dependencies have now all succeeded."""
    ready = []
    for dependent_id in dependents(session, [job_id]):
        # Lock the dependent first: two dependencies finishing at once must not both
        # see the other as unfinished and leave the dependent waiting forever.
        job = session.scalar(select(Job).where(Job.id == dependent_id).with_for_update())
        if job is None or job.status != "waiting":
            continue
        unfinished = session.scalar(
            select(func.count())
            .select_from(JobDependency)
            .join(Job, Job.id == JobDependency.depends_on_id)
            .where(JobDependency.job_id == dependent_id, Job.status != "succeeded")
        )
        if unfinished == 0:
            job.status = "queued"
            job.message = "ready"
            record_update(session, "job", job)
            ready.append(Dispatch(job.id, job.queue))
    return ready


def cancel_dependents(session: Session, job_id: int, reason: str) -> None:
    """Cancel every job downstream of ``job_id`` that has not started."""
    frontier = [job_id]
    while frontier:
        children = dependents(session, frontier)
        frontier = []
        for child in session.scalars(
            select(Job).where(Job.id.in_(children), Job.status.in_(NOT_STARTED))
        ):
            child.status = "cancelled"
            child.message = reason
            child.finished_at = utcnow()
            record_update(session, "job", child)
            frontier.append(child.id)
