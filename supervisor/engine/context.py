"""The engine's ``JobContext`` (see ``contract.context``): a claimed job's parameters and
inputs, progress written to its row, cancellation, staged outputs.

Outputs (artifacts, defects) are staged while the handler runs and recorded in the same
transaction that marks the job succeeded, so a failed or lost attempt leaves nothing.
"""

from __future__ import annotations

import json
import re
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel
from sqlalchemy import select, update

from contract.context import InputArtifact, NewDefect
from contract.errors import JobCancelled, JobLost
from contract.tolerances import Tolerances
from supervisor.engine.port import StagedArtifact
from supervisor.engine.runtime import Runtime
from supervisor.models import Job, JobLogLine
from supervisor.models._types import utcnow

PROGRESS_WRITE_INTERVAL_S = 0.25
MAX_LOG_LINES = 1000
"""Progress messages kept per attempt (the job's run page lists them)."""
_SCRATCH_NAME = re.compile(r"job(\d+)-a(\d+)-")


def scratch_prefix(job_id: int, attempt: int) -> str:
    """The start of an attempt's scratch folder name: the job and attempt that own it, so
    a folder left by a killed worker is told from one in use (``scratch_owner``)."""
    return f"job{job_id}-a{attempt}-"


def scratch_owner(name: str) -> tuple[int, int] | None:
    """The (job id, attempt) a scratch folder named ``name`` belongs to; None if it is
    not one."""
    match = _SCRATCH_NAME.match(name)
    return (int(match[1]), int(match[2])) if match else None


@dataclass(frozen=True)
class JobClaim:
    """A job this worker has claimed for one attempt."""

    id: int
    kind: str
    queue: str
    step: str
    run_id: int
    inspection_id: int
    params: dict
    attempt: int
    max_attempts: int
    inputs: tuple[InputArtifact, ...]
    tolerances: dict = field(default_factory=dict)
    """The inspection's acceptance limits (its ``tolerances`` document) when the job was
    claimed; the handler sees them as a ``Tolerances`` model."""
    cancel_requested: bool = False
    """A cancel asked for before this attempt began (the previous one's worker died)."""


class StopSignal:
    """Set by the heartbeat thread or a progress write; read by the handler."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.reason: type[Exception] | None = None
        self.detail = ""

    def set(self, reason: type[Exception], detail: str) -> None:
        if not self._event.is_set():
            self.reason, self.detail = reason, detail
            self._event.set()

    def raise_if_set(self) -> None:
        if self._event.is_set() and self.reason is not None:
            raise self.reason(self.detail)

    def wait(self, seconds: float) -> bool:
        return self._event.wait(seconds)


class WorkerContext:
    """A ``contract.context.JobContext`` for one attempt of a claimed job."""

    def __init__(
        self, runtime: Runtime, claim: JobClaim, params: BaseModel, stop: StopSignal
    ) -> None:
        self._runtime = runtime
        self.claim = claim
        self.kind = claim.kind
        self.params = params
        self.attempt = claim.attempt
        self.tolerances = Tolerances.model_validate(claim.tolerances)
        self.threads = runtime.settings.job_threads
        self.inputs = claim.inputs
        self.stop = stop
        self.staged: list[StagedArtifact] = []
        self.defects: list[NewDefect] = []
        self._last_write = 0.0
        self._last_logged, self._logged = "", 0
        self._workdir: Path | None = None

    @property
    def workdir(self) -> Path:
        """A private scratch folder for this attempt, removed when it ends (one left by a
        killed worker is removed at the next start-up, see ``remove_leftovers``)."""
        if self._workdir is None:
            root = self._runtime.scratch_dir
            root.mkdir(mode=0o700, parents=True, exist_ok=True)
            prefix = scratch_prefix(self.claim.id, self.claim.attempt)
            self._workdir = Path(tempfile.mkdtemp(prefix=prefix, dir=root))
        return self._workdir

    def check_cancelled(self) -> None:
        self.stop.raise_if_set()

    def progress(self, fraction: float, message: str = "") -> None:
        """Report progress (0..1); raises ``JobCancelled`` once cancellation was asked."""
        self.stop.raise_if_set()
        now = time.monotonic()
        if now - self._last_write < PROGRESS_WRITE_INTERVAL_S and fraction < 1.0:
            return
        self._last_write = now
        self._write_progress(min(max(float(fraction), 0.0), 1.0), message)
        self.stop.raise_if_set()

    def _write_progress(self, fraction: float, message: str) -> None:
        claim = self.claim
        with self._runtime.db.write() as session:
            values: dict[str, Any] = {"progress": fraction, "heartbeat_at": utcnow()}
            if message and self._workdir is not None:  # the log shows no server path
                message = message.replace(str(self._workdir), "the job's folder")
            if message:
                values["message"] = message[:2000]
            updated = session.execute(
                update(Job)
                .where(Job.id == claim.id, Job.status == "running", Job.attempts == claim.attempt)
                .values(**values)
            ).rowcount
            if (
                updated
                and message
                and message != self._last_logged
                and self._logged < MAX_LOG_LINES
            ):
                session.add(
                    JobLogLine(
                        job_id=claim.id,
                        attempt=claim.attempt,
                        progress=fraction,
                        message=message[:2000],
                    )
                )
                self._last_logged, self._logged = message, self._logged + 1
            cancel = session.scalar(select(Job.cancel_requested).where(Job.id == claim.id))
        if not updated:
            self.stop.set(JobLost, "another worker took this job over")
        elif cancel:
            self.stop.set(JobCancelled, "cancelled on request")

    def add_artifact_file(
        self, path: Path, *, kind: str, name: str, media_type: str, meta: dict | None = None
    ) -> None:
        stored = self._runtime.storage.put_file(
            Path(path), inspection_id=self.claim.inspection_id, name=name
        )
        self.staged.append(StagedArtifact(kind, name, media_type, stored, meta or {}))

    def add_artifact_json(self, data: dict, *, kind: str, name: str) -> None:
        payload = json.dumps(data, indent=2, sort_keys=True).encode()
        stored = self._runtime.storage.put_bytes(
            payload, inspection_id=self.claim.inspection_id, name=name
        )
        self.staged.append(StagedArtifact(kind, name, "application/json", stored, {}))

    def add_defect(self, defect: NewDefect) -> None:
        self.defects.append(defect)

    def discard_outputs(self) -> None:
        for artifact in self.staged:
            self._runtime.storage.delete(artifact.stored.uri)
        self.staged.clear()
        self.defects.clear()

    def close(self) -> None:
        if self._workdir is not None:
            shutil.rmtree(self._workdir, ignore_errors=True)
