"""The module ``dramatiq`` loads in ``vista worker``: broker, actors, maintenance."""

from __future__ import annotations

import dramatiq
from dramatiq.middleware import Middleware

from supervisor.engine.dramatiq_actors import actors_for, make_broker
from supervisor.engine.maintenance import MaintenanceLoop
from supervisor.engine.registry import load_kinds
from supervisor.settings import get_settings


class _Maintenance(Middleware):
    """Each worker process also recovers lost jobs and resends unsent ones."""

    def __init__(self) -> None:
        self._loop: MaintenanceLoop | None = None

    def after_worker_boot(self, broker, worker) -> None:  # type: ignore[no-untyped-def]
        from supervisor.engine.runner import default_runtime

        self._loop = MaintenanceLoop(default_runtime())
        self._loop.start()

    def before_worker_shutdown(self, broker, worker) -> None:  # type: ignore[no-untyped-def]
        if self._loop is not None:
            self._loop.stop()


_settings = get_settings()
if not _settings.broker_url:
    raise SystemExit("vista worker needs VISTA_BROKER_URL (redis://… or amqp://…)")
load_kinds(_settings.extra_job_kinds)
broker = make_broker(_settings.broker_url)
broker.add_middleware(_Maintenance())
dramatiq.set_broker(broker)
actors = actors_for(broker)
