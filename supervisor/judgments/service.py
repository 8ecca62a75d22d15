"""One current judgment per (user, defect), every version kept.

The write is an atomic upsert that bumps ``revision`` only when something changed, so
concurrent writers never lose an update and a retried PUT adds nothing. It is the API's
hottest path, so it is plain SQL built once: on PostgreSQL one statement in one round
trip, on SQLite (in-process, where round trips cost nothing) a short transaction.
"""

from __future__ import annotations

from collections import defaultdict

from sqlalchemy import Insert, bindparam, insert, or_, select, text
from sqlalchemy.dialects import sqlite
from sqlalchemy.engine import Row
from sqlalchemy.orm import Session

from supervisor.db import Database
from supervisor.defects.schemas import Consensus
from supervisor.defects.service import consensus_for, tally
from supervisor.defects.service import get as get_defect
from supervisor.judgments.schemas import (
    DefectJudgmentsOut,
    JudgmentIn,
    JudgmentOut,
    JudgmentRevisionOut,
)
from supervisor.models import Change, Defect, Judgment, JudgmentRevision, User
from supervisor.models._types import UTCDateTime, utcnow
from supervisor.problems import Problem, not_found

_judgments = Judgment.__table__
_revisions = JudgmentRevision.__table__
_changes = Change.__table__
_defects = Defect.__table__


def _sqlite_upsert() -> Insert:
    statement = sqlite.insert(_judgments).values(
        defect_id=bindparam("defect_id"),
        user_id=bindparam("user_id"),
        verdict=bindparam("verdict"),
        new_type=bindparam("new_type"),
        comment=bindparam("comment"),
        revision=1,
        updated_at=bindparam("now"),
        client_time=bindparam("now"),
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
            "client_time": incoming.client_time,
        },
        where=or_(
            _judgments.c.verdict != incoming.verdict,
            _judgments.c.new_type.is_distinct_from(incoming.new_type),
            _judgments.c.comment != incoming.comment,
        ),
    ).returning(*_judgments.c)


_SQLITE_UPSERT = _sqlite_upsert()


_DEFECT_FOR_JUDGMENT = select(_defects.c.inspection_id, _defects.c.type).where(
    _defects.c.id == bindparam("defect_id")
)
_ADD_REVISION = insert(_revisions)
_ADD_CHANGE = insert(_changes)
_CURRENT = select(_judgments).where(
    _judgments.c.defect_id == bindparam("defect_id"), _judgments.c.user_id == bindparam("user_id")
)

# PostgreSQL does the whole write in one statement (data-modifying CTEs), run in
# autocommit: one round trip instead of seven. Every part sees the same snapshot, so the
# votes are the other users' judgments plus the caller's row as it now stands.
_PG_PUT = text(
    """
WITH d AS (
    SELECT id, inspection_id, type FROM defects WHERE id = :defect_id
), up AS (
    INSERT INTO judgments AS j (defect_id, user_id, verdict, new_type, comment, revision,
                                updated_at, client_time)
    SELECT d.id, :user_id, :verdict, :new_type, :comment, 1, :now, :now FROM d
    WHERE NOT (CAST(:verdict AS varchar) = 'reclassified' AND d.type IS NOT DISTINCT FROM CAST(:new_type AS varchar))
    ON CONFLICT (defect_id, user_id) DO UPDATE SET
        verdict = excluded.verdict, new_type = excluded.new_type, comment = excluded.comment,
        revision = j.revision + 1, updated_at = excluded.updated_at,
        client_time = excluded.client_time
    WHERE j.verdict <> excluded.verdict OR j.new_type IS DISTINCT FROM excluded.new_type
        OR j.comment <> excluded.comment
    RETURNING j.*
), revision AS (
    INSERT INTO judgment_revisions (defect_id, user_id, revision, verdict, new_type, comment,
                                    client_time, created_at)
    SELECT defect_id, user_id, revision, verdict, new_type, comment, client_time, updated_at
    FROM up
), change AS (
    INSERT INTO changes (entity, entity_id, op, inspection_id, user_id, created_at)
    SELECT 'judgment', up.defect_id, 'update', d.inspection_id, up.user_id, up.updated_at
    FROM up, d
), mine AS (
    SELECT * FROM up
    UNION ALL
    SELECT * FROM judgments
    WHERE defect_id = :defect_id AND user_id = :user_id AND NOT EXISTS (SELECT FROM up)
)
SELECT d.type AS defect_type, mine.defect_id, mine.user_id, mine.verdict, mine.new_type,
       mine.comment, mine.revision, mine.updated_at, mine.client_time,
       (SELECT coalesce(json_agg(json_build_array(v.verdict, v.new_type)), '[]')
        FROM (SELECT verdict, new_type FROM judgments
              WHERE defect_id = :defect_id AND user_id <> :user_id
              UNION ALL SELECT verdict, new_type FROM mine) AS v) AS votes
FROM d LEFT JOIN mine ON true
"""
).columns(updated_at=UTCDateTime(), client_time=UTCDateTime())


def same_type_refusal(verdict: str, new_type: str | None, defect_type: str) -> str | None:
    """Why a reclassification to the defect's own type is refused, or None when it isn't one."""
    if verdict == "reclassified" and new_type == defect_type:
        return f"new_type: the defect already is a {defect_type}; pick another type."
    return None


def _refuse_same_type(data: JudgmentIn, defect_type: str) -> None:
    refusal = same_type_refusal(data.verdict, data.new_type, defect_type)
    if refusal:
        raise Problem(422, refusal)


def put_mine(
    db: Database, *, defect_id: int, user_id: int, data: JudgmentIn
) -> tuple[Row, Consensus]:
    """Upsert the caller's judgment, committed; returns its current row and the consensus."""
    values = {
        "defect_id": defect_id,
        "user_id": user_id,
        "verdict": data.verdict,
        "new_type": data.new_type,
        "comment": data.comment,
        "now": utcnow(),
    }
    if db.is_sqlite:
        with db.write() as session:
            row = _put_in_transaction(session, data, values)
            return row, consensus_for(session, [defect_id])[defect_id]
    with db.autocommit() as connection:
        row = connection.execute(_PG_PUT, values).first()
    if row is None:
        raise not_found("defect", defect_id)
    _refuse_same_type(data, row.defect_type)
    return row, tally((verdict, new_type, 1) for verdict, new_type in row.votes)


def _put_in_transaction(session: Session, data: JudgmentIn, values: dict) -> Row:
    defect = session.execute(_DEFECT_FOR_JUDGMENT, values).first()
    if defect is None:
        raise not_found("defect", values["defect_id"])
    _refuse_same_type(data, defect.type)
    row = session.execute(_SQLITE_UPSERT, values).first()
    if row is None:  # nothing changed: the same judgment again
        return session.execute(_CURRENT, values).one()
    now = values["now"]
    session.execute(
        _ADD_REVISION,
        {**values, "revision": row.revision, "client_time": now, "created_at": now},
    )
    session.execute(
        _ADD_CHANGE,
        {
            "entity": "judgment",
            "entity_id": values["defect_id"],
            "op": "update",
            "inspection_id": defect.inspection_id,
            "user_id": values["user_id"],
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
        client_time=judgment.client_time,
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
