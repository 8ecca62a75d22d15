"""One current judgment per (user, defect), every version kept.

The write is a single atomic upsert that bumps ``revision`` only when something
changed, so concurrent writers never lose an update and a retried PUT adds nothing.
It is the API's hottest path, so it is plain SQL Core with statements built once.
"""

from __future__ import annotations

from collections import defaultdict
from functools import cache

from sqlalchemy import Insert, bindparam, insert, or_, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import Row
from sqlalchemy.orm import Session

from supervisor.defects.service import consensus_for
from supervisor.defects.service import get as get_defect
from supervisor.judgments.schemas import (
    DefectJudgmentsOut,
    JudgmentIn,
    JudgmentOut,
    JudgmentRevisionOut,
)
from supervisor.models import Change, Defect, Judgment, JudgmentRevision, User
from supervisor.models._types import utcnow
from supervisor.problems import Problem, not_found

_judgments = Judgment.__table__
_revisions = JudgmentRevision.__table__
_changes = Change.__table__
_defects = Defect.__table__


@cache
def _upsert(dialect: str) -> Insert:
    module = postgresql if dialect == "postgresql" else sqlite
    statement = module.insert(_judgments).values(
        defect_id=bindparam("defect_id"),
        user_id=bindparam("user_id"),
        verdict=bindparam("verdict"),
        new_type=bindparam("new_type"),
        comment=bindparam("comment"),
        revision=1,
        updated_at=bindparam("now"),
    )
    incoming = statement.excluded
    return statement.on_conflict_do_update(
        index_elements=[_judgments.c.defect_id, _judgments.c.user_id],
        set_={
            "verdict": incoming.verdict,
            "new_type": incoming.new_type,
            "comment": incoming.comment,
            "revision": _judgments.c.revision + 1,
            "updated_at": incoming.updated_at,
        },
        where=or_(
            _judgments.c.verdict != incoming.verdict,
            _judgments.c.new_type.is_distinct_from(incoming.new_type),
            _judgments.c.comment != incoming.comment,
        ),
    ).returning(*_judgments.c)


_DEFECT_FOR_JUDGMENT = select(_defects.c.inspection_id, _defects.c.type).where(
    _defects.c.id == bindparam("defect_id")
)
_ADD_REVISION = insert(_revisions)
_ADD_CHANGE = insert(_changes)
_CURRENT = select(_judgments).where(
    _judgments.c.defect_id == bindparam("defect_id"), _judgments.c.user_id == bindparam("user_id")
)


def put_mine(session: Session, *, defect_id: int, user_id: int, data: JudgmentIn) -> Row:
    """Upsert the caller's judgment; returns the current ``judgments`` row."""
    defect = session.execute(_DEFECT_FOR_JUDGMENT, {"defect_id": defect_id}).first()
    if defect is None:
        raise not_found("defect", defect_id)
    if data.verdict == "reclassified" and data.new_type == defect.type:
        raise Problem(422, f"new_type: the defect already is a {defect.type}; pick another type.")
    now = utcnow()
    values = {
        "defect_id": defect_id,
        "user_id": user_id,
        "verdict": data.verdict,
        "new_type": data.new_type,
        "comment": data.comment,
    }
    row = session.execute(_upsert(session.get_bind().dialect.name), {**values, "now": now}).first()
    if row is None:  # nothing changed: the same judgment again
        return session.execute(_CURRENT, values).one()
    session.execute(_ADD_REVISION, {**values, "revision": row.revision, "created_at": now})
    session.execute(
        _ADD_CHANGE,
        {
            "entity": "judgment",
            "entity_id": defect_id,
            "op": "update",
            "inspection_id": defect.inspection_id,
            "user_id": user_id,
            "created_at": now,
        },
    )
    return row


def judgment_out(judgment: Row | Judgment, username: str) -> JudgmentOut:
    return JudgmentOut(
        defect_id=judgment.defect_id,
        user_id=judgment.user_id,
        username=username,
        verdict=judgment.verdict,
        new_type=judgment.new_type,
        comment=judgment.comment,
        revision=judgment.revision,
        updated_at=judgment.updated_at,
    )


def all_for_defect(session: Session, *, defect_id: int) -> DefectJudgmentsOut:
    get_defect(session, defect_id=defect_id)
    history: dict[int, list[JudgmentRevisionOut]] = defaultdict(list)
    for revision in session.scalars(
        select(JudgmentRevision)
        .where(JudgmentRevision.defect_id == defect_id)
        .order_by(JudgmentRevision.user_id, JudgmentRevision.revision)
    ):
        history[revision.user_id].append(JudgmentRevisionOut.model_validate(revision))
    judgments = []
    for judgment, username in session.execute(
        select(Judgment, User.username)
        .join(User, User.id == Judgment.user_id)
        .where(Judgment.defect_id == defect_id)
        .order_by(Judgment.updated_at)
    ):
        out = judgment_out(judgment, username)
        out.history = history[judgment.user_id]
        judgments.append(out)
    return DefectJudgmentsOut(
        defect_id=defect_id,
        consensus=consensus_for(session, [defect_id])[defect_id],
        judgments=judgments,
    )
