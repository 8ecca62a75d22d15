"""``run_job(job_id)``: the one function that executes a job, on any engine.

1. Claim the row atomically (``UPDATE … WHERE status='queued'``); if that changes no
   row the job is finished, cancelled or running elsewhere and this call does nothing.
2. Run the registered handler with a ``JobContext`` while a heartbeat thread keeps the
   row alive, watches for cancellation and enforces the time limit.
3. Record outputs, defects and the final status in one transaction guarded by the
   attempt number, so a worker that was presumed dead cannot overwrite its successor.
4. After commit, send the jobs that this one's success made ready.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from datetime import timedelta

from pydantic import ValidationError
from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session

from contract.context import InputArtifact
from contract.errors import JobCancelled, JobInputError, JobLost, JobTimeLimit
from supervisor.changes import record_update
from supervisor.engine.context import JobClaim, StopSignal, WorkerContext
from supervisor.engine.dispatch import Dispatch, dispatch
from supervisor.engine.port import JobOutputs
from supervisor.engine.registry import get_kind
from supervisor.engine.runtime import Runtime, worker_name
from supervisor.engine.transient import is_transient
from supervisor.engine.transitions import end_attempt
from supervisor.models import Inspection, Job
from supervisor.models._types import utcnow

log = logging.getLogger("vista.engine")


def run_job(job_id: int, *, runtime: Runtime) -> str:
    """Execute job ``job_id`` once if it is queued; returns the status it ended in."""
    rt = runtime
    claim = claim_job(rt, job_id)
    if claim is None:
        return "skipped"
    if claim.cancel_requested:  # the cancel outlives the attempt it was asked of
        return _end(rt, claim, status="cancelled", message="cancelled on request", error=None)
    kind = get_kind(claim.kind)
    stop = StopSignal()
    try:
        if kind is None:
            raise LookupError(f"job kind {claim.kind!r} is not known to this worker")
        params = kind.params.model_validate(claim.params)
    except LookupError as exc:
        return _end_failed(rt, claim, sentence(str(exc)))
    except ValidationError as exc:
        return _end_failed(rt, claim, _first_error("params", exc))
    try:
        ctx = WorkerContext(rt, claim, params, stop)
    except ValidationError as exc:  # stored before today's rules: fix them through the API
        return _end_failed(rt, claim, _first_error("the inspection's tolerances", exc))
    beat = _Heartbeat(rt, claim, stop)
    beat.start()
    error: BaseException | None = None
    try:
        result = kind.load_handler()(ctx)
    except BaseException as exc:  # every way out is recorded
        result, error = None, exc
    finally:
        beat.stop()
    try:
        if error is not None:
            ctx.discard_outputs()
            return _end_after_error(rt, claim, error)
        return _end_succeeded(rt, claim, ctx, result or {})
    finally:
        ctx.close()


def claim_job(rt: Runtime, job_id: int) -> JobClaim | None:
    now = utcnow()
    with rt.db.write() as session:
        claimed = session.execute(
            update(Job)
            .where(
                Job.id == job_id,
                Job.status == "queued",
                or_(Job.not_before.is_(None), Job.not_before <= now),
            )
            .values(
                status="running",
                attempts=Job.attempts + 1,
                started_at=now,
                heartbeat_at=now,
                worker=worker_name(),
                progress=0.0,
                message="started",
                error=None,
            )
        ).rowcount
        if claimed != 1:
            return None
        job = session.get(Job, job_id)
        assert job is not None
        record_update(session, "job", job)
        return JobClaim(
            id=job.id,
            kind=job.kind,
            queue=job.queue,
            step=job.step,
            run_id=job.run_id,
            inspection_id=job.inspection_id,
            params=dict(job.params or {}),
            attempt=job.attempts,
            max_attempts=job.max_attempts,
            inputs=_inputs(rt, session, job),
            cancel_requested=bool(job.cancel_requested),
            tolerances=dict(
                session.scalar(
                    select(Inspection.tolerances).where(Inspection.id == job.inspection_id)
                )
                or {}
            ),
        )


def _inputs(rt: Runtime, session: Session, job: Job) -> tuple[InputArtifact, ...]:
    return tuple(
        InputArtifact(
            id=a.id,
            kind=a.kind,
            name=a.name,
            media_type=a.media_type,
            path=rt.storage.path(a.storage_uri),
            meta=dict(a.meta or {}),
            job_id=a.job_id,
        )
        for a in rt.records.inputs(session, job)
    )


class _Heartbeat:
    """Beats every ``heartbeat_interval_s``; flags cancellation, loss and the time limit."""

    def __init__(self, rt: Runtime, claim: JobClaim, stop: StopSignal) -> None:
        self._rt, self._claim, self._stop = rt, claim, stop
        self._done = threading.Event()
        self._thread = threading.Thread(
            target=self._loop, name=f"heartbeat-{claim.id}", daemon=True
        )
        self._started = time.monotonic()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._done.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=10)

    def _loop(self) -> None:
        interval = self._rt.settings.heartbeat_interval_s
        limit = self._rt.settings.job_time_limit_s
        claim = self._claim
        while not self._done.wait(interval):
            if time.monotonic() - self._started > limit:
                self._stop.set(JobTimeLimit, f"the attempt ran past the time limit of {limit} s")
            try:
                with self._rt.db.write() as session:
                    alive = session.execute(
                        update(Job)
                        .where(
                            Job.id == claim.id,
                            Job.status == "running",
                            Job.attempts == claim.attempt,
                        )
                        .values(heartbeat_at=utcnow())
                    ).rowcount
                    cancel = session.scalar(select(Job.cancel_requested).where(Job.id == claim.id))
            except Exception:  # a missed beat is retried next interval
                log.warning("heartbeat of job %s failed", claim.id, exc_info=True)
                continue
            if not alive:
                self._stop.set(JobLost, "another worker took this job over")
            elif cancel:
                self._stop.set(JobCancelled, "cancelled on request")


def _end_succeeded(rt: Runtime, claim: JobClaim, ctx: WorkerContext, result: dict) -> str:
    with rt.db.write() as session:
        ready = end_attempt(
            session,
            claim.id,
            claim.attempt,
            records=rt.records,
            status="succeeded",
            progress=1.0,
            result=result,
            # a result's warning (what was not done) is its last word, not "done"
            message=f"done, with a warning: {result['warning']}"
            if result.get("warning")
            else "done",
            finished_at=utcnow(),
        )
        if ready is None:
            session.rollback()
            ctx.discard_outputs()
            return "lost"
        rt.records.record_outputs(
            session,
            JobOutputs(
                job_id=claim.id,
                inspection_id=claim.inspection_id,
                run_id=claim.run_id,
                artifacts=tuple(ctx.staged),
                findings=tuple(ctx.defects),
            ),
        )
    dispatch(rt.db, rt.dispatcher, ready)
    return "succeeded"


def _end(rt: Runtime, claim: JobClaim, *, status: str, message: str, error: str | None) -> str:
    with rt.db.write() as session:
        ended = end_attempt(
            session,
            claim.id,
            claim.attempt,
            records=rt.records,
            status=status,
            message=message,
            error=error,
            finished_at=utcnow(),
        )
    return status if ended is not None else "lost"


def _first_error(where: str, exc: ValidationError) -> str:
    first = exc.errors()[0]
    at = ".".join([where, *(str(p) for p in first["loc"])])
    return sentence(f"{at}: {first['msg']}")


def _end_failed(rt: Runtime, claim: JobClaim, error: str) -> str:
    return _end(rt, claim, status="failed", message="failed", error=error)


def _end_after_error(rt: Runtime, claim: JobClaim, exc: BaseException) -> str:
    if isinstance(exc, JobLost):
        return "lost"
    if isinstance(exc, JobCancelled):
        return _end(rt, claim, status="cancelled", message=str(exc), error=None)
    if isinstance(exc, JobTimeLimit):
        return _end_failed(rt, claim, sentence(str(exc)))
    if is_transient(exc) and claim.attempt < claim.max_attempts:
        return _requeue(rt, claim, exc)
    if not isinstance(exc, Exception):
        log.error("job %s interrupted by %s", claim.id, type(exc).__name__)
        _end_failed(rt, claim, f"Interrupted by {type(exc).__name__}.")
        raise exc
    if isinstance(exc, JobInputError):
        log.warning("job %s (%s, step %r) failed: %s", claim.id, claim.kind, claim.step, exc)
    else:
        log.error("job %s (%s, step %r) failed", claim.id, claim.kind, claim.step, exc_info=exc)
    return _end_failed(rt, claim, user_error(exc, claim, rt.settings.job_memory_mb))


def user_error(exc: Exception, claim: JobClaim, memory_mb: int) -> str:
    """One sentence a user can act on; the traceback stays in the worker's log."""
    if isinstance(exc, JobInputError):
        return sentence(str(exc))
    if isinstance(exc, MemoryError):  # not a passing fault: another attempt needs as much
        needs = f" ({exc})" if str(exc) else ""
        return sentence(
            f"{claim.kind} needs more memory than a worker allows{needs}: the worker allows "
            f"{memory_mb / 1024:.1f} GiB (VISTA_JOB_MEMORY_MB); give the workers more, or "
            "send a smaller input"
        )
    text = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    if is_transient(exc):
        return sentence(
            f"{claim.kind} failed in all {claim.attempt} attempts on a passing fault ({text}); "
            "retry the job once it is fixed"
        )
    return sentence(
        f"{claim.kind} stopped on an unexpected error ({text}); the worker's log has the "
        f"details under job {claim.id}"
    )


def sentence(text: str, *, max_chars: int = 500) -> str:
    """``text`` on one line, without directories of server paths nor Markdown's code marks
    (`model` reads 'model'), capitalised and ended."""
    line = " ".join(_CODE.sub(r"'\1'", _DIRECTORIES.sub("", text)).split())
    if len(line) > max_chars:
        line = line[: max_chars - 1].rstrip() + "…"
    line = line[:1].upper() + line[1:]
    return line if line.endswith((".", "!", "?", "…")) else line + "."


_DIRECTORIES = re.compile(r"(?<![\w.:/])(?:/[\w.-]+)+/")
_CODE = re.compile(r"`([^`]+)`")


def _requeue(rt: Runtime, claim: JobClaim, exc: BaseException) -> str:
    delay_s = rt.settings.retry_backoff_s * 2 ** (claim.attempt - 1)
    with rt.db.write() as session:
        cancel = session.scalar(select(Job.cancel_requested).where(Job.id == claim.id))
    if cancel:  # asked to stop: not another attempt
        return _end(rt, claim, status="cancelled", message="cancelled on request", error=None)
    with rt.db.write() as session:
        requeued = end_attempt(
            session,
            claim.id,
            claim.attempt,
            records=rt.records,
            status="queued",
            not_before=utcnow() + timedelta(seconds=delay_s),
            dispatched_at=None,
            worker=None,
            message=f"retrying in {delay_s:.0f} s after: {type(exc).__name__}: {exc}"[:2000],
        )
    if requeued is None:
        return "lost"
    dispatch(rt.db, rt.dispatcher, [Dispatch(claim.id, claim.queue, delay_s)])
    return "queued"
