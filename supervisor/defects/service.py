from __future__ import annotations

import math
from collections.abc import Iterable

from sqlalchemy import bindparam, func, select
from sqlalchemy.orm import Session

from supervisor.changes import record_change
from supervisor.defects.schemas import Consensus, DefectCreate, DefectOut
from supervisor.models import Defect, Inspection, Judgment
from supervisor.models.defects import VERDICTS
from supervisor.problems import Problem, not_found

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


READING_KEYS = ("value", "unit", "tolerance")


def reading(value_mm: float | None, tolerance_mm: float | None, measurements: dict | None) -> dict:
    """A defect's value, unit and tolerance: from its measurements (where a non-millimetre
    value such as a colour ΔE lives), else its millimetre columns."""
    measurements = measurements or {}
    return {
        "value": measurements.get("value", value_mm),
        "unit": measurements.get("unit", "mm"),
        "tolerance": measurements.get("tolerance", tolerance_mm),
    }


def defects_out(session: Session, defects: list[Defect]) -> list[DefectOut]:
    consensus = consensus_for(session, [d.id for d in defects])
    out = []
    for defect in defects:
        item = DefectOut.model_validate(defect)
        item.consensus = consensus[defect.id]
        out.append(item)
    return out


def get(session: Session, *, defect_id: int) -> Defect:
    defect = session.get(Defect, defect_id)
    if defect is None:
        raise not_found("defect", defect_id)
    return defect


def create(session: Session, *, data: DefectCreate, user_id: int) -> Defect:
    if session.get(Inspection, data.inspection_id) is None:
        raise Problem(422, f"inspection_id: there is no inspection with id {data.inspection_id}.")
    norm = math.sqrt(sum(c * c for c in data.normal))
    if norm < 1e-9:
        raise Problem(422, "normal: must not be the zero vector.")
    defect = Defect(
        inspection_id=data.inspection_id,
        type=data.type,
        status="open",
        value_mm=data.value_mm,
        tolerance_mm=data.tolerance_mm,
        measurements={},
        location_mm=list(data.location_mm),
        normal=[c / norm for c in data.normal],
        extent_mm=data.extent_mm,
        severity=data.severity,
        confidence=data.confidence,
        source="manual",
    )
    session.add(defect)
    session.flush()
    record_change(
        session,
        entity="defect",
        entity_id=defect.id,
        op="create",
        inspection_id=defect.inspection_id,
        user_id=user_id,
    )
    return defect


def set_status(session: Session, *, defect_id: int, status: str, user_id: int) -> Defect:
    defect = get(session, defect_id=defect_id)
    defect.status = status
    record_change(
        session,
        entity="defect",
        entity_id=defect.id,
        op="update",
        inspection_id=defect.inspection_id,
        user_id=user_id,
    )
    session.flush()
    return defect
