"""Dramatiq broker and one actor per service queue, shared by senders and workers."""

from __future__ import annotations

import dramatiq
from dramatiq.brokers.rabbitmq import RabbitmqBroker
from dramatiq.brokers.redis import RedisBroker

from supervisor.engine.errors import is_transient
from supervisor.engine.registry import queues
from supervisor.settings import get_settings

ACTOR_PREFIX = "vista_run_job__"
MAX_TRANSPORT_RETRIES = 5


def make_broker(url: str) -> dramatiq.Broker:
    if url.startswith(("redis://", "rediss://", "unix://")):
        return RedisBroker(url=url)
    if url.startswith(("amqp://", "amqps://")):
        return RabbitmqBroker(url=url)
    raise ValueError(f"VISTA_BROKER_URL must be redis://… or amqp://…, got {url!r}")


def _retry_transient(retries: int, exc: BaseException) -> bool:
    """Dramatiq retries only what failed outside a handler (e.g. the database was away)."""
    return retries < MAX_TRANSPORT_RETRIES and is_transient(exc)


def _run_job_message(job_id: int) -> None:
    from supervisor.engine.runner import run_job

    run_job(job_id)


def actors_for(broker: dramatiq.Broker) -> dict[str, dramatiq.Actor]:
    """Declare (once per broker) the actor of every known queue."""
    settings = get_settings()
    limit_ms = (settings.job_time_limit_s + 600) * 1000
    actors: dict[str, dramatiq.Actor] = {}
    for queue in queues():
        name = ACTOR_PREFIX + queue
        if name in broker.actors:
            actors[queue] = broker.get_actor(name)
            continue
        actors[queue] = dramatiq.actor(
            _run_job_message,
            actor_name=name,
            queue_name=queue,
            broker=broker,
            time_limit=limit_ms,
            retry_when=_retry_transient,
            min_backoff=1000,
            max_backoff=60_000,
        )
    return actors
