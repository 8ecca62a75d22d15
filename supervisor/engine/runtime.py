"""What a process needs to run or dispatch jobs: settings, database, storage, dispatcher."""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass

from supervisor.db import Database
from supervisor.engine.dispatch import Dispatcher, make_dispatcher
from supervisor.engine.registry import load_kinds
from supervisor.settings import Settings
from supervisor.storage import Storage


@dataclass
class Runtime:
    settings: Settings
    db: Database
    storage: Storage
    dispatcher: Dispatcher

    @classmethod
    def create(cls, settings: Settings, *, database: Database | None = None) -> Runtime:
        load_kinds(settings.extra_job_kinds)
        return cls(
            settings=settings,
            db=database or Database(settings.resolved_database_url),
            storage=Storage(settings.resolved_artifact_dir),
            dispatcher=make_dispatcher(settings.broker_url),
        )


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"
