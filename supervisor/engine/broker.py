"""The Dramatiq broker and the names of the messages that carry job ids.

Senders enqueue a message by its actor's name; only ``vista worker`` (``supervisor.worker_app``)
declares the actors that run them, so sending a job never imports the runner.
"""

from __future__ import annotations

import dramatiq
from dramatiq.brokers.rabbitmq import RabbitmqBroker
from dramatiq.brokers.redis import RedisBroker

ACTOR_PREFIX = "vista_run_job__"


def make_broker(url: str) -> dramatiq.Broker:
    if url.startswith(("redis://", "rediss://", "unix://")):
        return RedisBroker(url=url)
    if url.startswith(("amqp://", "amqps://")):
        return RabbitmqBroker(url=url)
    raise ValueError(f"VISTA_BROKER_URL must be redis://… or amqp://…, got {url!r}")


def actor_name(queue: str) -> str:
    """The actor that runs the jobs of ``queue``."""
    return ACTOR_PREFIX + queue


def job_message(queue: str, job_id: int) -> dramatiq.Message:
    return dramatiq.Message(
        queue_name=queue, actor_name=actor_name(queue), args=(job_id,), kwargs={}, options={}
    )
