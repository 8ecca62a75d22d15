"""Keeping the job table honest: lost workers, jobs that were never sent and the
scratch folders of attempts that ended; and, once at start-up, the unfinished files that
killed processes left behind.

Any number of processes may run this (the supervisor and every worker do): each step is
a conditional UPDATE, so two of them acting on the same job cannot both win.
"""

from __future__ import annotations

import logging
import shutil
import signal
import threading
from collections.abc import Callable
from datetime import timedelta

from sqlalchemy import ColumnElement, or_, select

from supervisor.engine.context import scratch_owner
from supervisor.engine.dispatch import Dispatch, dispatch
from supervisor.engine.runtime import Runtime
from supervisor.engine.transitions import end_attempt
from supervisor.models import Job
from supervisor.models._types import utcnow
from supervisor.storage import Removed, tree_size

log = logging.getLogger("vista.engine")
RESEND_AFTER_S = 5.0
STALE_TEMP_AGE_S = 6 * 3600.0
"""A storage ``.part`` file untouched this long belongs to no live upload or job output:
an upload writes to it as its bytes arrive, and from its last byte to its rename into
place only checks run (minutes for the largest upload). So several API processes and
workers sharing the storage folder can each clean it at start-up."""


def recover_lost_jobs(rt: Runtime) -> list[int]:
    """Re-queue (or fail, when out of attempts) running jobs whose heartbeat stopped."""
    timeout = rt.settings.heartbeat_timeout_s
    still_silent = Job.heartbeat_at < utcnow() - timedelta(seconds=timeout)
    return release_jobs(
        rt,
        still_silent,
        lambda worker: f"worker {worker or '?'} lost: no heartbeat for {timeout:.0f} s",
    )


def release_jobs_of_worker(rt: Runtime, worker: str, exit_code: int | None) -> list[int]:
    """Re-queue (or fail) the jobs of ``worker`` (a ``Job.worker`` name) at once, when
    the process that runs it was seen to exit: nobody needs to wait for its heartbeat
    to stop."""
    ended = f"worker {worker} exited ({_exit_description(exit_code)})"
    return release_jobs(rt, Job.worker == worker, lambda _worker: ended)


def _exit_description(exit_code: int | None) -> str:
    """``exit code 1``, or ``exit code -9, killed by SIGKILL`` for a signal."""
    if exit_code is None:
        return "exit code unknown"
    if exit_code < 0:
        try:
            return f"exit code {exit_code}, killed by {signal.Signals(-exit_code).name}"
        except ValueError:
            pass
    return f"exit code {exit_code}"


def release_jobs(
    rt: Runtime, condition: ColumnElement[bool], reason: Callable[[str | None], str]
) -> list[int]:
    """Re-queue (or fail, when out of attempts; or cancel, when a cancel was asked for)
    the running jobs that meet ``condition`` (their worker is gone); ``reason(worker)``
    says why, for the job's message and error.
    ``condition`` guards each job's update too, so a job that beat again or ended in the
    meantime is left alone, and two processes releasing one job cannot both win."""
    with rt.db.read() as session:
        lost = session.execute(
            select(
                Job.id, Job.attempts, Job.max_attempts, Job.worker, Job.queue, Job.cancel_requested
            ).where(Job.status == "running", condition)
        ).all()
    touched, resend = [], []
    for job_id, attempts, max_attempts, worker, queue, cancel in lost:
        why = reason(worker)
        with rt.db.write() as session:
            if cancel:  # asked to stop: its worker's death does not undo that
                ended = end_attempt(
                    session,
                    job_id,
                    attempts,
                    records=rt.records,
                    status="cancelled",
                    guard=(condition,),
                    message=f"cancelled on request ({why} before it stopped)",
                    finished_at=utcnow(),
                )
            elif attempts < max_attempts:
                ended = end_attempt(
                    session,
                    job_id,
                    attempts,
                    records=rt.records,
                    status="queued",
                    guard=(condition,),
                    worker=None,
                    dispatched_at=None,
                    not_before=None,
                    message=f"{why} in attempt {attempts}; re-queued",
                )
                if ended is not None:
                    resend.append(Dispatch(job_id, queue))
            else:
                ended = end_attempt(
                    session,
                    job_id,
                    attempts,
                    records=rt.records,
                    status="failed",
                    guard=(condition,),
                    message="failed",
                    error=f"The {why} in attempt {attempts} of {max_attempts}; "
                    "it may have run out of memory or been stopped (see its log).",
                    finished_at=utcnow(),
                )
            if ended is not None:
                touched.append(job_id)
                log.warning("job %s: %s", job_id, why)
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


def remove_leftovers(rt: Runtime) -> None:
    """Remove what killed processes left behind (a crash leaves them; a clean stop does
    not): unfinished files in the storage's temporary folder and the scratch folders of
    job attempts that are no longer running; logs what went and how much."""
    files = rt.storage.remove_stale_temp_files(older_than_s=STALE_TEMP_AGE_S)
    folders = remove_stale_scratch(rt)
    if files.count or folders.count:
        log.info(
            "removed leftovers of stopped processes: %d unfinished file(s) (%.1f MB) in %s, "
            "%d scratch folder(s) of ended job attempts (%.1f MB) in %s",
            files.count,
            files.size_bytes / 1e6,
            rt.storage.root / "tmp",
            folders.count,
            folders.size_bytes / 1e6,
            rt.scratch_dir,
        )


def remove_stale_scratch(rt: Runtime) -> Removed:
    """Remove the scratch folders whose job attempt is not running per the database.

    The folders are listed before the running attempts are read: a folder is made only
    after its attempt was claimed (committed as running), so a listed folder whose
    attempt is not running then has ended (or was taken as lost) and nobody uses it."""
    try:
        listed = [(p, owner) for p in rt.scratch_dir.iterdir() if (owner := scratch_owner(p.name))]
    except FileNotFoundError:
        return Removed(0, 0)
    if not listed:
        return Removed(0, 0)
    with rt.db.read() as session:
        rows = session.execute(select(Job.id, Job.attempts).where(Job.status == "running"))
        running = {(job_id, attempt) for job_id, attempt in rows}
    count = size_bytes = 0
    for path, owner in listed:
        if owner in running:
            continue
        size = tree_size(path)
        shutil.rmtree(path, ignore_errors=True)
        if not path.exists():
            count, size_bytes = count + 1, size_bytes + size
    return Removed(count, size_bytes)


class MaintenanceLoop:
    """A daemon thread that first removes leftovers of stopped processes, then runs the
    maintenance steps every heartbeat interval."""

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
        try:
            remove_leftovers(self._rt)
        except Exception:  # a folder it cannot read stays for the next start
            log.warning("removing leftovers of stopped processes failed", exc_info=True)
        while not self._stop.wait(interval):
            try:
                recover_lost_jobs(self._rt)
                resend_queued(self._rt)
                # a killed attempt's scratch goes once the attempt is not running, not
                # at the next start-up only
                remove_stale_scratch(self._rt)
            except Exception:  # the next round tries again
                log.warning("job maintenance failed", exc_info=True)
