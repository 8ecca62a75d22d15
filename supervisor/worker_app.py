"""The module ``dramatiq`` loads in ``vista worker``: the broker, one actor per service
queue running ``run_job``, and the maintenance loop — the engine assembled with the
domains' side of its port (``supervisor.records``)."""

from __future__ import annotations

from functools import lru_cache

import dramatiq
from dramatiq.middleware import Middleware

from services.lib.process import limit_address_space, prepare_process
from supervisor.engine.broker import actor_name, make_broker
from supervisor.engine.maintenance import MaintenanceLoop
from supervisor.engine.registry import load_kinds, queues
from supervisor.engine.runner import run_job
from supervisor.engine.runtime import Runtime
from supervisor.engine.transient import is_transient
from supervisor.records import DomainRecords
from supervisor.settings import get_settings

MAX_TRANSPORT_RETRIES = 5


class _Maintenance(Middleware):
    """Each worker process also recovers lost jobs and resends unsent ones."""

    def __init__(self) -> None:
        self._loop: MaintenanceLoop | None = None

    def after_worker_boot(self, broker: dramatiq.Broker, worker: dramatiq.Worker) -> None:
        self._loop = MaintenanceLoop(_runtime())
        self._loop.start()

    def before_worker_shutdown(self, broker: dramatiq.Broker, worker: dramatiq.Worker) -> None:
        if self._loop is not None:
            self._loop.stop()


def _retry_transient(retries: int, exc: BaseException) -> bool:
    """Dramatiq retries only what failed outside a handler (e.g. the database was away)."""
    return retries < MAX_TRANSPORT_RETRIES and is_transient(exc)


@lru_cache
def _runtime() -> Runtime:
    """This worker process's database, storage and dispatcher, made on first use."""
    return Runtime.create(get_settings(), records=DomainRecords())


def _run_job_message(job_id: int) -> None:
    run_job(job_id, runtime=_runtime())


prepare_process()  # each worker process imports this module
_settings = get_settings()
if not _settings.broker_url:
    raise SystemExit("vista worker needs VISTA_BROKER_URL (redis://… or amqp://…)")
limit_address_space(_settings.job_memory_mb)
load_kinds(_settings.extra_job_kinds)
broker = make_broker(_settings.broker_url)
broker.add_middleware(_Maintenance())
dramatiq.set_broker(broker)
actors = {
    queue: dramatiq.actor(
        _run_job_message,
        actor_name=actor_name(queue),
        queue_name=queue,
        broker=broker,
        time_limit=(_settings.job_time_limit_s + 600) * 1000,
        retry_when=_retry_transient,
        min_backoff=1000,
        max_backoff=60_000,
    )
    for queue in queues()
}
