"""The embedded engine: worker processes beside the API that poll the database.

No broker is needed: a worker claims the oldest queued job that is due (the claim in
``run_job`` is atomic, so several workers never run one job twice). A worker that dies
is restarted, and the maintenance loop re-queues the job it held once its heartbeat
stops.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import signal
import threading

from sqlalchemy import or_, select

from services.process import prepare_process
from supervisor.engine.runner import run_job
from supervisor.engine.runtime import Runtime
from supervisor.models import Job
from supervisor.models._types import utcnow
from supervisor.settings import Settings

log = logging.getLogger("vista.engine")
IDLE_POLL_S = 0.2


def next_due_jobs(rt: Runtime, limit: int = 4) -> list[int]:
    with rt.db.read() as session:
        return list(
            session.scalars(
                select(Job.id)
                .where(
                    Job.status == "queued",
                    or_(Job.not_before.is_(None), Job.not_before <= utcnow()),
                )
                .order_by(Job.id)
                .limit(limit)
            )
        )


def _worker_main(settings_json: str, stop: mp.synchronize.Event) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when workers stop
    prepare_process()
    rt = Runtime.create(Settings.model_validate_json(settings_json))
    while not stop.is_set():
        ran = False
        for job_id in next_due_jobs(rt):
            if run_job(job_id, runtime=rt) != "skipped":
                ran = True
                break
        if not ran:
            stop.wait(IDLE_POLL_S)
    rt.db.dispose()


class EmbeddedPool:
    def __init__(self, settings: Settings, processes: int) -> None:
        self._settings_json = settings.model_dump_json()
        self._count = processes
        self._ctx = mp.get_context("spawn")
        self._stop = self._ctx.Event()
        self._procs: list[mp.process.BaseProcess] = []
        self._monitor_stop = threading.Event()
        self._monitor = threading.Thread(target=self._watch, name="vista-pool-monitor", daemon=True)

    @property
    def pids(self) -> list[int]:
        return [p.pid for p in self._procs if p.pid is not None and p.is_alive()]

    def _spawn(self) -> mp.process.BaseProcess:
        proc = self._ctx.Process(
            target=_worker_main,
            args=(self._settings_json, self._stop),
            name="vista-worker",
            daemon=True,
        )
        proc.start()
        return proc

    def start(self) -> None:
        self._procs = [self._spawn() for _ in range(self._count)]
        self._monitor.start()

    def _watch(self) -> None:
        while not self._monitor_stop.wait(0.5):
            for index, proc in enumerate(self._procs):
                if not proc.is_alive() and not self._stop.is_set():
                    log.warning(
                        "embedded worker %s exited (%s); restarting", proc.pid, proc.exitcode
                    )
                    self._procs[index] = self._spawn()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._monitor_stop.set()
        self._stop.set()
        if self._monitor.is_alive():
            self._monitor.join(timeout=2)
        for proc in self._procs:
            proc.join(timeout=timeout_s)
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=2)
