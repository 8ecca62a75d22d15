"""One current judgment per (user, defect), every version kept.

The write is a single atomic upsert that bumps ``revision`` only when something
changed, so concurrent writers never lose an update and a retried PUT adds nothing.
"""

from __future__ import annotations

from collections import defaultdict

from sqlalchemy import insert, or_, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from supervisor.changes import record_change
from supervisor.defects.service import consensus_for
from supervisor.defects.service import get as get_defect
from supervisor.judgments.schemas import (
    DefectJudgmentsOut,
    JudgmentIn,
    JudgmentOut,
    JudgmentRevisionOut,
)
from supervisor.models import Judgment, JudgmentRevision, User
from supervisor.models._types import utcnow
from supervisor.problems import Problem


def _upsert(session: Session):  # noqa: ANN202 - the dialect's INSERT construct
    return (postgresql if session.get_bind().dialect.name == "postgresql" else sqlite).insert(
        Judgment
    )


def put_mine(session: Session, *, defect_id: int, user_id: int, data: JudgmentIn) -> Judgment:
    defect = get_defect(session, defect_id=defect_id)
    if data.verdict == "reclassified" and data.new_type == defect.type:
        raise Problem(422, f"new_type: the defect already is a {defect.type}; pick another type.")
    now = utcnow()
    statement = _upsert(session).values(
        defect_id=defect_id,
        user_id=user_id,
        verdict=data.verdict,
        new_type=data.new_type,
        comment=data.comment,
        revision=1,
        updated_at=now,
    )
    incoming = statement.excluded
    statement = statement.on_conflict_do_update(
        index_elements=[Judgment.defect_id, Judgment.user_id],
        set_={
            "verdict": incoming.verdict,
            "new_type": incoming.new_type,
            "comment": incoming.comment,
            "revision": Judgment.revision + 1,
            "updated_at": incoming.updated_at,
        },
        where=or_(
            Judgment.verdict != incoming.verdict,
            Judgment.new_type.is_distinct_from(incoming.new_type),
            Judgment.comment != incoming.comment,
        ),
    ).returning(Judgment.revision)
    revision = session.execute(statement).scalar_one_or_none()
    if revision is not None:
        session.execute(
            insert(JudgmentRevision).values(
                defect_id=defect_id,
                user_id=user_id,
                revision=revision,
                verdict=data.verdict,
                new_type=data.new_type,
                comment=data.comment,
                created_at=now,
            )
        )
        record_change(
            session,
            entity="judgment",
            entity_id=defect_id,
            op="update",
            inspection_id=defect.inspection_id,
            user_id=user_id,
        )
    return session.scalars(
        select(Judgment).where(Judgment.defect_id == defect_id, Judgment.user_id == user_id)
    ).one()


def judgment_out(judgment: Judgment, username: str) -> JudgmentOut:
    return JudgmentOut(
        defect_id=judgment.defect_id,
        user_id=judgment.user_id,
        username=username,
        verdict=judgment.verdict,  # type: ignore[arg-type]
        new_type=judgment.new_type,  # type: ignore[arg-type]
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
