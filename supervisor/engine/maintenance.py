"""Keeping the job table honest: lost workers and jobs that were never sent.

Any number of processes may run this (the supervisor and every worker do): each step is
a conditional UPDATE, so two of them acting on the same job cannot both win.
"""

from __future__ import annotations

import logging
import threading
from datetime import timedelta

from sqlalchemy import or_, select

from supervisor.engine.dispatch import Dispatch, dispatch
from supervisor.engine.runtime import Runtime
from supervisor.engine.transitions import end_attempt
from supervisor.models import Job
from supervisor.models._types import utcnow

log = logging.getLogger("vista.engine")
RESEND_AFTER_S = 5.0


def recover_lost_jobs(rt: Runtime) -> list[int]:
    """Re-queue (or fail, when out of attempts) running jobs whose heartbeat stopped."""
    timeout = rt.settings.heartbeat_timeout_s
    cutoff = utcnow() - timedelta(seconds=timeout)
    with rt.db.read() as session:
        lost = session.execute(
            select(Job.id, Job.attempts, Job.max_attempts, Job.worker, Job.queue).where(
                Job.status == "running", Job.heartbeat_at < cutoff
            )
        ).all()
    touched, resend = [], []
    for job_id, attempts, max_attempts, worker, queue in lost:
        silence = f"worker {worker or '?'} lost: no heartbeat for {timeout:.0f} s"
        still_silent = (Job.heartbeat_at < cutoff,)
        with rt.db.write() as session:
            if attempts < max_attempts:
                ended = end_attempt(
                    session,
                    job_id,
                    attempts,
                    status="queued",
                    guard=still_silent,
                    worker=None,
                    dispatched_at=None,
                    not_before=None,
                    message=f"{silence} in attempt {attempts}; re-queued",
                )
                if ended is not None:
                    resend.append(Dispatch(job_id, queue))
            else:
                ended = end_attempt(
                    session,
                    job_id,
                    attempts,
                    status="failed",
                    guard=still_silent,
                    message="failed",
                    error=f"The {silence} in attempt {attempts} of {max_attempts}; "
                    "it may have run out of memory or been stopped (see its log).",
                    finished_at=utcnow(),
                )
            if ended is not None:
                touched.append(job_id)
                log.warning("job %s: %s", job_id, silence)
    dispatch(rt.db, rt.dispatcher, resend)
    return touched


def resend_queued(rt: Runtime, *, only_undispatched: bool = True) -> int:
    """Send queued jobs again: those never sent (or, at start-up, all of them)."""
    if rt.dispatcher.polls_database:
        return 0
    query = select(Job.id, Job.queue, Job.not_before).where(Job.status == "queued")
    if only_undispatched:
        cutoff = utcnow() - timedelta(seconds=RESEND_AFTER_S)
        query = query.where(
            Job.dispatched_at.is_(None), or_(Job.not_before.is_(None), Job.not_before < cutoff)
        )
    with rt.db.read() as session:
        rows = session.execute(query).all()
    now = utcnow()
    items = [
        Dispatch(job_id, queue, max(0.0, (not_before - now).total_seconds()) if not_before else 0.0)
        for job_id, queue, not_before in rows
    ]
    dispatch(rt.db, rt.dispatcher, items)
    return len(items)


class MaintenanceLoop:
    """A daemon thread running the maintenance steps every heartbeat interval."""

    def __init__(self, rt: Runtime) -> None:
        self._rt = rt
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="vista-maintenance", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def _loop(self) -> None:
        interval = min(
            self._rt.settings.heartbeat_interval_s, self._rt.settings.heartbeat_timeout_s / 2
        )
        while not self._stop.wait(interval):
            try:
                recover_lost_jobs(self._rt)
                resend_queued(self._rt)
            except Exception:  # the next round tries again
                log.warning("job maintenance failed", exc_info=True)
