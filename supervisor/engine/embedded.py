"""The embedded engine: worker processes beside the API that poll the database.

No broker is needed: a worker claims the oldest queued job that is due (the claim in
``run_job`` is atomic, so several workers never run one job twice). A worker that dies
is restarted, and the job it held is re-queued at once (``release_jobs_of_worker``), not
after its heartbeat timeout. Workers live and die with the server: a killed server's
workers get SIGTERM from the kernel (``die_with_parent``), and a worker that finds
itself adopted by another parent stops polling, so no orphan takes jobs beside the
restarted server's own workers.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import threading

from sqlalchemy import or_, select

from services.lib.process import (
    die_with_parent,
    limit_address_space,
    parent_alive,
    prepare_process,
)
from supervisor.engine.maintenance import release_jobs_of_worker
from supervisor.engine.port import JobRecords
from supervisor.engine.runner import run_job
from supervisor.engine.runtime import Runtime, worker_name
from supervisor.models import Job
from supervisor.models._types import utcnow
from supervisor.settings import Settings

log = logging.getLogger("vista.engine")
IDLE_POLL_S = 0.2
WATCH_INTERVAL_S = 0.5


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


def _worker_main(
    settings_json: str, records: JobRecords, stop: mp.synchronize.Event, parent_pid: int
) -> None:
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when workers stop
    prepare_process()
    settings = Settings.model_validate_json(settings_json)
    limit_address_space(settings.job_memory_mb)
    rt = Runtime.create(settings, records=records)
    while not stop.is_set() and parent_alive(parent_pid):
        ran = False
        for job_id in next_due_jobs(rt):
            if run_job(job_id, runtime=rt) != "skipped":
                ran = True
                break
        if not ran:
            stop.wait(IDLE_POLL_S)
    rt.db.dispose()


class EmbeddedPool:
    """``processes`` worker processes, restarted when they die, stopped with the server.

    Every worker is started by the monitor thread, which ends only after the workers
    have: the kernel's parent-death signal follows the thread that started a process."""

    def __init__(self, runtime: Runtime, processes: int) -> None:
        self._rt = runtime
        self._settings_json = runtime.settings.model_dump_json()
        self._count = processes
        self._ctx = mp.get_context("spawn")
        self._stop = self._ctx.Event()
        self._procs: list[mp.process.BaseProcess] = []
        self._spawning = threading.Lock()  # no worker starts once stop() began
        self._monitor_stop = threading.Event()
        self._monitor = threading.Thread(target=self._watch, name="vista-pool-monitor", daemon=True)

    @property
    def pids(self) -> list[int]:
        return [p.pid for p in self._procs if p.pid is not None and p.is_alive()]

    def _spawn(self) -> mp.process.BaseProcess:
        proc = self._ctx.Process(
            target=_worker_main,
            args=(self._settings_json, self._rt.records, self._stop, os.getpid()),
            name="vista-worker",
            daemon=True,
        )
        proc.start()
        return proc

    def start(self) -> None:
        self._monitor.start()

    def _watch(self) -> None:
        with self._spawning:
            if not self._stop.is_set():
                self._procs = [self._spawn() for _ in range(self._count)]
        while not self._monitor_stop.wait(WATCH_INTERVAL_S):
            for index, proc in enumerate(self._procs):
                if not proc.is_alive() and not self._stop.is_set():
                    self._replace(index, proc)

    def _replace(self, index: int, dead: mp.process.BaseProcess) -> None:
        """Release the jobs the dead worker held, then start another in its place."""
        log.warning("embedded worker %s exited (%s); restarting", dead.pid, dead.exitcode)
        if dead.pid is not None:
            try:
                release_jobs_of_worker(self._rt, worker_name(dead.pid), dead.exitcode)
            except Exception:  # the heartbeat timeout still recovers its jobs
                log.warning("releasing the jobs of worker %s failed", dead.pid, exc_info=True)
        with self._spawning:
            if not self._stop.is_set():
                self._procs[index] = self._spawn()

    def stop(self, timeout_s: float = 10.0) -> None:
        with self._spawning:
            self._stop.set()
        for proc in self._procs:
            proc.join(timeout=timeout_s)
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=2)
        self._monitor_stop.set()
        if self._monitor.is_alive():
            self._monitor.join(timeout=2)
