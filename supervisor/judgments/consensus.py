"""The reviewers' consensus on a defect, from everyone's current judgment."""

from __future__ import annotations

from collections.abc import Iterable

from sqlalchemy import bindparam, func, select
from sqlalchemy.orm import Session

from supervisor.defects.schemas import Consensus
from supervisor.models import Judgment
from supervisor.models.defects import VERDICTS

AGREEMENT_NEEDED = 2 / 3


def consensus_from(counts: dict[str, int], reclassified_as: dict[str, int]) -> Consensus:
    full = {v: counts.get(v, 0) for v in VERDICTS}
    total = sum(full.values())
    ranked = sorted(full.items(), key=lambda item: -item[1])
    top_verdict, top = ranked[0]
    majority = top_verdict if total and top > ranked[1][1] else None
    agreement = top / total if total else 0.0
    needs_review = total > 0 and (
        majority is None or majority == "uncertain" or agreement < AGREEMENT_NEEDED
    )
    return Consensus(
        counts=full,  # type: ignore[arg-type]
        total=total,
        majority=majority,  # type: ignore[arg-type]
        agreement=agreement,
        needs_review=needs_review,
        reclassified_as=reclassified_as,
    )


_VOTES = (
    select(Judgment.defect_id, Judgment.verdict, Judgment.new_type, func.count())
    .where(Judgment.defect_id.in_(bindparam("defect_ids", expanding=True)))
    .group_by(Judgment.defect_id, Judgment.verdict, Judgment.new_type)
)


def tally(votes: Iterable[tuple[str, str | None, int]]) -> Consensus:
    """The consensus of (verdict, new type, how many) votes on one defect."""
    counts: dict[str, int] = {}
    retyped: dict[str, int] = {}
    for verdict, new_type, count in votes:
        counts[verdict] = counts.get(verdict, 0) + count
        if verdict == "reclassified" and new_type:
            retyped[new_type] = retyped.get(new_type, 0) + count
    return consensus_from(counts, retyped)


Votes = list[tuple[str, str | None, int]]


def votes_for(session: Session, defect_ids: Iterable[int]) -> dict[int, Votes]:
    """The (verdict, new type, how many) votes of each of these defects that has any."""
    ids = list(defect_ids)
    votes: dict[int, Votes] = {}
    if ids:
        for defect_id, verdict, new_type, count in session.execute(_VOTES, {"defect_ids": ids}):
            votes.setdefault(defect_id, []).append((verdict, new_type, count))
    return votes


def consensus_for(session: Session, defect_ids: list[int]) -> dict[int, Consensus]:
    votes = votes_for(session, defect_ids)
    return {d: tally(votes.get(d, [])) for d in defect_ids}


def consensus_docs(session: Session, defect_ids: Iterable[int]) -> list[dict]:
    """The consensus of each of these defects that has judgments."""
    votes = votes_for(session, defect_ids)
    return [
        {"defect_id": defect_id, **tally(v).model_dump(mode="json")}
        for defect_id, v in sorted(votes.items())
    ]
