"""Reading and writing judgments; the write itself is ``judgments.write``."""

from __future__ import annotations

from collections import defaultdict

from sqlalchemy import select
from sqlalchemy.engine import Row
from sqlalchemy.orm import Session

from supervisor.db import Database
from supervisor.defects.schemas import Consensus
from supervisor.defects.service import get as get_defect
from supervisor.judgments.consensus import consensus_for, tally
from supervisor.judgments.schemas import (
    DefectJudgmentsOut,
    JudgmentIn,
    JudgmentOut,
    JudgmentRevisionOut,
)
from supervisor.judgments.write import JudgmentWrite, same_type_refusal, write
from supervisor.models import Judgment, JudgmentRevision, User
from supervisor.models._types import utcnow
from supervisor.problems import Problem, not_found


def put_mine(
    db: Database, *, defect_id: int, user_id: int, data: JudgmentIn
) -> tuple[Row, Consensus]:
    """Upsert the caller's judgment, committed; returns its current row and the consensus."""
    now = utcnow()
    judgment = JudgmentWrite.of(
        data, defect_id=defect_id, user_id=user_id, client_time=now, now=now
    )
    if db.is_sqlite:
        with db.write() as session:
            written = write(session, judgment)
    else:
        with db.autocommit() as connection:  # one statement: no BEGIN/COMMIT trips
            written = write(connection, judgment)
    if written.defect_type is None:
        raise not_found("defect", defect_id)
    if written.refused:
        raise Problem(422, same_type_refusal(written.defect_type))
    assert written.judgment is not None
    return written.judgment, tally((verdict, new_type, 1) for verdict, new_type in written.votes)


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
        judged_on_run_id=judgment.judged_on_run_id,
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
