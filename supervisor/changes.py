"""Writing the change log: every change to a synced entity appends one row."""

from __future__ import annotations

from typing import Any

from sqlalchemy import insert
from sqlalchemy.orm import Session

from supervisor.models import Change


def record_change(
    session: Session,
    *,
    entity: str,
    entity_id: int,
    op: str,
    inspection_id: int | None,
    user_id: int | None = None,
) -> None:
    session.execute(
        insert(Change).values(
            entity=entity,
            entity_id=entity_id,
            op=op,
            inspection_id=inspection_id,
            user_id=user_id,
        )
    )


def record_changes(
    session: Session,
    *,
    entity: str,
    entity_ids: list[int],
    op: str,
    inspection_id: int | None,
    user_id: int | None = None,
) -> None:
    """``record_change`` for many rows of one entity at once."""
    session.execute(
        insert(Change),
        [
            {
                "entity": entity,
                "entity_id": entity_id,
                "op": op,
                "inspection_id": inspection_id,
                "user_id": user_id,
            }
            for entity_id in entity_ids
        ],
    )


def add_created(session: Session, entity: str, row: object, user_id: int) -> None:
    """Add a new row and log its creation (see ``record_update``)."""
    session.add(row)
    session.flush()
    _record(session, entity, row, "create", user_id)


def record_update(session: Session, entity: str, row: object, user_id: int | None = None) -> None:
    """Log an update of ``row``: one with ``id`` and ``inspection_id`` (an inspection is
    logged under itself)."""
    _record(session, entity, row, "update", user_id)


def _record(session: Session, entity: str, row: Any, op: str, user_id: int | None) -> None:
    record_change(
        session,
        entity=entity,
        entity_id=row.id,
        op=op,
        inspection_id=row.id if entity == "inspection" else row.inspection_id,
        user_id=user_id,
    )
