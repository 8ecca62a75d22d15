"""The one judgment write, used by ``PUT /defects/{id}/judgments/me`` and the headset's
sync push.

One current judgment per (user, defect), every version kept. The write is an atomic
upsert that bumps ``revision`` only when something changed, so concurrent writers never
lose an update and a repeated judgment adds nothing; a changed judgment also appends its
revision and a change-log row. A reclassification to the defect's own type is refused
(``same_type``, the one place the rule lives).

It is the API's hottest path, so each dialect gets one statement set built once from the
pieces below: on PostgreSQL a single statement (data-modifying CTEs) in one round trip;
on SQLite (in-process, where round trips cost nothing) the same pieces run in turn in a
short transaction.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import (
    ColumnElement,
    FromClause,
    Insert,
    Select,
    and_,
    bindparam,
    exists,
    false,
    func,
    insert,
    literal,
    not_,
    or_,
    select,
    true,
    union_all,
)
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import Connection, Row
from sqlalchemy.orm import Session
from sqlalchemy.types import JSON

from supervisor.judgments.schemas import JudgmentIn
from supervisor.models import Change, Defect, Inspection, Judgment, JudgmentRevision

_judgments = Judgment.__table__
_revisions = JudgmentRevision.__table__
_changes = Change.__table__
_defects = Defect.__table__
_inspections = Inspection.__table__

_DEFECT_ID = bindparam("defect_id", type_=_judgments.c.defect_id.type)
_USER_ID = bindparam("user_id", type_=_judgments.c.user_id.type)
_VERDICT = bindparam("verdict", type_=_judgments.c.verdict.type)
_NEW_TYPE = bindparam("new_type", type_=_judgments.c.new_type.type)
_COMMENT = bindparam("comment", type_=_judgments.c.comment.type)
_CLIENT_TIME = bindparam("client_time", type_=_judgments.c.client_time.type)
_NOW = bindparam("now", type_=_judgments.c.updated_at.type)
_NEWER_ONLY = bindparam("newer_only", type_=_judgments.c.revision.type)
_JUDGED_ON = bindparam("judged_on_run_id", type_=_judgments.c.judged_on_run_id.type)


@dataclass(frozen=True)
class JudgmentWrite:
    """One user's judgment of one defect, as given."""

    defect_id: int
    user_id: int
    verdict: str
    new_type: str | None
    comment: str
    client_time: datetime
    """When the judgment was made (the server's time for a PUT, the headset's offline)."""
    now: datetime
    newer_only: bool = False
    """Keep a stored judgment made after ``client_time`` (the sync's rule; a PUT always wins)."""
    judged_on_run_id: int | None = None
    """The run of the earlier finding the user judged, when the judgment was sent for a
    finding a later measurement has since superseded (None: judged on this one)."""

    @classmethod
    def of(
        cls,
        given: JudgmentIn,
        *,
        defect_id: int,
        user_id: int,
        client_time: datetime,
        now: datetime,
        newer_only: bool = False,
        judged_on_run_id: int | None = None,
    ) -> JudgmentWrite:
        return cls(
            defect_id=defect_id,
            user_id=user_id,
            verdict=given.verdict,
            new_type=given.new_type,
            comment=given.comment,
            client_time=client_time,
            now=now,
            newer_only=newer_only,
            judged_on_run_id=judged_on_run_id,
        )

    def params(self) -> dict:
        return {
            "defect_id": self.defect_id,
            "user_id": self.user_id,
            "verdict": self.verdict,
            "new_type": self.new_type,
            "comment": self.comment,
            "client_time": self.client_time,
            "now": self.now,
            "newer_only": int(self.newer_only),
            "judged_on_run_id": self.judged_on_run_id,
        }


@dataclass(frozen=True)
class Written:
    """What a write found and left."""

    defect_type: str | None
    """The defect's type; None when there is no such defect (nothing written)."""
    refused: bool
    """A reclassification to the defect's own type: nothing written."""
    changed: bool
    """A new revision was written."""
    judgment: Row | None
    """The user's judgment as it now stands (None: the user has none)."""
    votes: list[tuple[str, str | None]]
    """Every user's current (verdict, new type) of the defect, for its consensus."""


def _the_defect() -> ColumnElement[bool]:
    """The defect judged, unless its inspection is in the trash (then it is not there)."""
    live = exists(
        select(_inspections.c.id).where(
            _inspections.c.id == _defects.c.inspection_id, _inspections.c.deleted_at.is_(None)
        )
    )
    return and_(_defects.c.id == _DEFECT_ID, live)


def same_type(defect_type: ColumnElement) -> ColumnElement[bool]:
    """The judgment being written reclassifies the defect as the type it already has."""
    return and_(_VERDICT == "reclassified", _NEW_TYPE.is_not_distinct_from(defect_type))


def same_type_refusal(defect_type: str) -> str:
    return f"new_type: the defect already is a {defect_type}; pick another type."


def _upsert(dialect_insert: type[postgresql.Insert] | type[sqlite.Insert]) -> Insert:
    """Insert the judgment, or update the user's one when something in it changed (and,
    with ``newer_only``, when it was made after the stored one); returns the row written."""
    source = select(
        _defects.c.id,
        _USER_ID,
        _VERDICT,
        _NEW_TYPE,
        _COMMENT,
        literal(1),
        _NOW,
        _CLIENT_TIME,
        _JUDGED_ON,
    ).where(_the_defect(), not_(same_type(_defects.c.type)))
    statement = dialect_insert(_judgments).from_select(
        ["defect_id", "user_id", "verdict", "new_type", "comment", "revision", "updated_at"]
        + ["client_time", "judged_on_run_id"],
        source,
    )
    stored, incoming = _judgments.c, statement.excluded
    return statement.on_conflict_do_update(
        index_elements=[stored.defect_id, stored.user_id],
        set_={
            "verdict": incoming.verdict,
            "new_type": incoming.new_type,
            "comment": incoming.comment,
            "revision": stored.revision + 1,
            "updated_at": incoming.updated_at,
            "client_time": incoming.client_time,
            "judged_on_run_id": incoming.judged_on_run_id,
        },
        where=and_(
            or_(
                stored.verdict != incoming.verdict,
                stored.new_type.is_distinct_from(incoming.new_type),
                stored.comment != incoming.comment,
            ),
            or_(
                _NEWER_ONLY == 0,
                stored.client_time.is_(None),
                stored.client_time < incoming.client_time,
            ),
        ),
    ).returning(*_judgments.c)


def _add_revision(written: FromClause) -> Insert:
    """Append the revision of each judgment in ``written``."""
    c = written.c
    return insert(_revisions).from_select(
        ["defect_id", "user_id", "revision", "verdict", "new_type", "comment", "client_time"]
        + ["judged_on_run_id", "created_at"],
        select(
            c.defect_id, c.user_id, c.revision, c.verdict, c.new_type, c.comment, c.client_time
        ).add_columns(c.judged_on_run_id, c.updated_at),
    )


def _add_change(written: FromClause) -> Insert:
    """Append a change-log row for each judgment in ``written``."""
    c = written.c
    return insert(_changes).from_select(
        ["entity", "entity_id", "op", "inspection_id", "user_id", "created_at"],
        select(
            literal("judgment"),
            c.defect_id,
            literal("update"),
            _defects.c.inspection_id,
            c.user_id,
            c.updated_at,
        ).where(_defects.c.id == c.defect_id),
    )


def _outcome(mine: FromClause, changed: ColumnElement[bool], votes: Select) -> Select:
    """The defect's type, the refusal, whether a revision was written, the user's judgment
    (``mine``) and every user's current vote as a JSON list; one row, or none without
    the defect."""
    return (
        select(
            _defects.c.type.label("defect_type"),
            same_type(_defects.c.type).label("refused"),
            changed.label("changed"),
            votes.scalar_subquery().label("votes"),
            *mine.c,
        )
        .select_from(_defects.outerjoin(mine, true()))
        .where(_the_defect())
    )


def _postgresql_write() -> Select:
    # Every part of the statement sees the snapshot from before the upsert: the votes are
    # the other users' judgments plus the caller's as it now stands (``mine``).
    up = _upsert(postgresql.insert).cte("up")
    mine = union_all(
        select(up),
        select(_judgments).where(
            _judgments.c.defect_id == _DEFECT_ID,
            _judgments.c.user_id == _USER_ID,
            not_(exists(select(up.c.id))),
        ),
    ).cte("mine")
    voters = union_all(
        select(_judgments.c.verdict, _judgments.c.new_type).where(
            _judgments.c.defect_id == _DEFECT_ID, _judgments.c.user_id != _USER_ID
        ),
        select(mine.c.verdict, mine.c.new_type).correlate(None),
    ).subquery("voters")
    votes = select(
        func.json_agg(func.json_build_array(voters.c.verdict, voters.c.new_type), type_=JSON)
    )
    return _outcome(mine, exists(select(up.c.id)), votes).add_cte(
        _add_revision(up).cte("revision"), _add_change(up).cte("change")
    )


def _current() -> Select:
    return select(_judgments).where(
        _judgments.c.defect_id == _DEFECT_ID, _judgments.c.user_id == _USER_ID
    )


def _sqlite_outcome() -> Select:
    votes = select(
        func.json_group_array(
            func.json_array(_judgments.c.verdict, _judgments.c.new_type), type_=JSON
        )
    ).where(_judgments.c.defect_id == _DEFECT_ID)
    return _outcome(_current().subquery("mine"), false(), votes)


_POSTGRESQL_WRITE = _postgresql_write()
_SQLITE_UPSERT = _upsert(sqlite.insert)
_SQLITE_ADD_REVISION = _add_revision(_current().subquery("written"))
_SQLITE_ADD_CHANGE = _add_change(_current().subquery("written"))
_SQLITE_OUTCOME = _sqlite_outcome()


def write(connection: Connection | Session, judgment: JudgmentWrite) -> Written:
    """Write ``judgment`` in the caller's transaction (or, on PostgreSQL, in autocommit)."""
    params = judgment.params()
    bind = connection.get_bind() if isinstance(connection, Session) else connection
    if bind.dialect.name == "sqlite":
        changed = connection.execute(_SQLITE_UPSERT, params).first() is not None
        if changed:
            connection.execute(_SQLITE_ADD_REVISION, params)
            connection.execute(_SQLITE_ADD_CHANGE, params)
        row = connection.execute(_SQLITE_OUTCOME, params).first()
    else:
        row = connection.execute(_POSTGRESQL_WRITE, params).first()
        changed = bool(row is not None and row.changed)
    if row is None:
        return Written(None, refused=False, changed=False, judgment=None, votes=[])
    return Written(
        defect_type=row.defect_type,
        refused=bool(row.refused),
        changed=changed,
        judgment=row if row.defect_id is not None else None,
        votes=[(verdict, new_type) for verdict, new_type in row.votes or []],
    )
