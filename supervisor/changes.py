"""Writing the change log: every change to a synced entity appends one row."""

from __future__ import annotations

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
