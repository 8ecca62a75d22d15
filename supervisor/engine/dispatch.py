"""Sending job ids to whoever runs them: the embedded pool or a Dramatiq broker.

A job is always committed to the database before it is sent, and only its id travels.
The database is the ledger: a send that fails leaves ``dispatched_at`` empty and the
maintenance loop sends it again.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

from sqlalchemy import update

from supervisor.db import Database
from supervisor.models import Job
from supervisor.models._types import utcnow

log = logging.getLogger("vista.engine")


@dataclass(frozen=True)
class Dispatch:
    job_id: int
    queue: str
    delay_s: float = 0.0


class Dispatcher(Protocol):
    polls_database: bool

    def send(self, item: Dispatch) -> None: ...


class EmbeddedDispatcher:
    """The embedded pool polls the database for queued jobs, so sending is a no-op."""

    polls_database = True

    def send(self, item: Dispatch) -> None:
        return None


class DramatiqDispatcher:
    """Sends each job id as a message to its queue's actor, by name."""

    polls_database = False

    def __init__(self, broker_url: str) -> None:
        from supervisor.engine.broker import make_broker

        self.broker = make_broker(broker_url)

    def send(self, item: Dispatch) -> None:
        from supervisor.engine.broker import job_message

        message = job_message(item.queue, item.job_id)
        self.broker.enqueue(message, delay=int(item.delay_s * 1000) or None)


def make_dispatcher(broker_url: str | None) -> Dispatcher:
    return DramatiqDispatcher(broker_url) if broker_url else EmbeddedDispatcher()


def dispatch(db: Database, dispatcher: Dispatcher, items: Iterable[Dispatch]) -> None:
    """Send each job and note when it was sent; failures are logged and retried later."""
    sent = []
    for item in items:
        try:
            dispatcher.send(item)
        except Exception:  # the maintenance loop resends undispatched jobs
            log.exception("could not send job %s to queue %s", item.job_id, item.queue)
            continue
        sent.append(item.job_id)
    if sent:
        with db.write() as session:
            session.execute(
                update(Job)
                .where(Job.id.in_(sent), Job.status == "queued")
                .values(dispatched_at=utcnow())
            )
