"""The audit log: every change of state — who, when, what, before → after.

Judgments keep their own full history (``judgment_revisions``, one row per version with
its author and time); everything else that changes state writes one ``AuditEvent`` here,
in the transaction of the change, so the log and the data never disagree.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

from sqlalchemy import insert
from sqlalchemy.orm import Session

from supervisor.models import AuditEvent


class Actor(Protocol):
    """Who acts: a signed-in user (``deps.CurrentUser``) or an ``Operator``."""

    @property
    def id(self) -> int | None: ...

    @property
    def username(self) -> str: ...


@dataclass(frozen=True)
class Operator:
    """Someone acting outside a signed-in request: at the command line on the server's
    machine, or a user signing in."""

    id: int | None = None
    username: str = "(command line)"


COMMAND_LINE = Operator()


def audit(
    session: Session,
    actor: Actor,
    action: str,
    *,
    entity: str,
    entity_id: int,
    inspection_id: int | None = None,
    before: dict[str, Any] | None = None,
    after: dict[str, Any] | None = None,
    reason: str = "",
) -> None:
    """Record one change of state; ``before``/``after`` hold only the fields it changed."""
    session.execute(
        insert(AuditEvent).values(
            user_id=actor.id,
            username=actor.username,
            action=action,
            entity=entity,
            entity_id=entity_id,
            inspection_id=inspection_id,
            before=before,
            after=after,
            reason=reason,
        )
    )


def changed_fields(before: dict[str, Any], after: dict[str, Any]) -> tuple[dict, dict]:
    """The fields whose value differs, as (before, after)."""
    keys = [key for key in after if before.get(key) != after[key]]
    return {key: before.get(key) for key in keys}, {key: after[key] for key in keys}
