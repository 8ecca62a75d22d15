"""What a process needs to run or dispatch jobs: settings, database, storage, dispatcher."""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from pathlib import Path

from supervisor.db import Database
from supervisor.engine.dispatch import Dispatcher, make_dispatcher
from supervisor.engine.port import JobRecords
from supervisor.engine.registry import load_kinds
from supervisor.settings import Settings
from supervisor.storage import Storage


@dataclass
class Runtime:
    settings: Settings
    db: Database
    storage: Storage
    dispatcher: Dispatcher
    records: JobRecords
    """The domains' side of the engine's port (``supervisor.engine.port``)."""

    @classmethod
    def create(
        cls, settings: Settings, *, records: JobRecords, database: Database | None = None
    ) -> Runtime:
        load_kinds(settings.extra_job_kinds)
        return cls(
            records=records,
            settings=settings,
            db=database
            or Database(
                settings.resolved_database_url, sqlite_synchronous=settings.sqlite_synchronous
            ),
            storage=Storage(settings.resolved_artifact_dir),
            dispatcher=make_dispatcher(settings.broker_url),
        )

    @property
    def scratch_dir(self) -> Path:
        """Where job attempts keep their scratch folders: in this deployment's data folder
        (not the machine's shared temp folder), so the folders found there belong to this
        deployment's database and a start-up can tell the stale ones by its jobs."""
        return self.settings.data_dir.resolve() / "scratch"


def worker_name(pid: int | None = None) -> str:
    """How a job's row names the process running it (``Job.worker``): host and pid, so
    the embedded pool can find the jobs of a worker that died (``pid``: that worker's;
    default this process)."""
    return f"{socket.gethostname()}:{pid or os.getpid()}"
