from __future__ import annotations

import math
from collections.abc import Sequence

from sqlalchemy import insert, or_, select, update
from sqlalchemy.orm import Session

from contract.context import NewDefect
from contract.findings import Reading
from supervisor.audit.service import Actor, audit
from supervisor.changes import record_changes, record_update
from supervisor.defects.schemas import DefectCreate, DefectHistoryOut, DefectOut, LineageStep
from supervisor.inspections.service import ensure_live
from supervisor.judgments.consensus import consensus_for
from supervisor.models import Defect, Inspection, JudgmentRevision, Run, User
from supervisor.models._types import utcnow
from supervisor.problems import Problem, not_found

READING_KEYS = tuple(Reading.model_fields)


def reading(value_mm: float | None, tolerance_mm: float | None, measurements: dict | None) -> dict:
    """A defect's value, unit and tolerance: from its measurements (where a non-millimetre
    value such as a colour ΔE lives), else its millimetre columns."""
    read = Reading.model_validate(measurements or {})
    return {
        "value": value_mm if read.value is None else read.value,
        "unit": read.unit,
        "tolerance": tolerance_mm if read.tolerance is None else read.tolerance,
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
    ensure_live(session, defect.inspection_id, "defect", defect_id)
    return defect


def record_defect(
    session: Session,
    finding: NewDefect,
    *,
    inspection_id: int,
    source: str,
    run_id: int | None = None,
    job_id: int | None = None,
    user_id: int | None = None,
) -> int:
    """One finding through ``record_defects``; returns its id."""
    (defect_id,) = record_defects(
        session,
        [finding],
        inspection_id=inspection_id,
        source=source,
        run_id=run_id,
        job_id=job_id,
        user_id=user_id,
    )
    return defect_id


LINEAGE_CHUNK = 1000
"""Ids per statement when a batch starts its lineages (well under SQLite's variables)."""


def record_defects(
    session: Session,
    findings: Sequence[NewDefect],
    *,
    inspection_id: int,
    source: str,
    run_id: int | None = None,
    job_id: int | None = None,
    user_id: int | None = None,
) -> list[int]:
    """The one way defect rows come to be (a job's findings, one reported by hand, a
    bench's seed): each row, open and the first of its lineage, and its change-log entry;
    returns their ids in the findings' order."""
    if not findings:
        return []
    rows = [
        {
            "inspection_id": inspection_id,
            "run_id": run_id,
            "job_id": job_id,
            "type": f.type,
            "status": "open",
            "value_mm": f.value_mm,
            "tolerance_mm": f.tolerance_mm,
            "measurements": f.measurements,
            "location_mm": list(f.location_mm),
            "normal": list(f.normal),
            "extent_mm": f.extent_mm,
            "severity": f.severity,
            "confidence": f.confidence,
            "source": source,
        }
        for f in findings
    ]
    ids = list(
        session.scalars(insert(Defect).returning(Defect.id, sort_by_parameter_order=True), rows)
    )
    for start in range(0, len(ids), LINEAGE_CHUNK):
        chunk = ids[start : start + LINEAGE_CHUNK]
        session.execute(update(Defect).where(Defect.id.in_(chunk)).values(lineage_id=Defect.id))
    record_changes(
        session,
        entity="defect",
        entity_ids=ids,
        op="create",
        inspection_id=inspection_id,
        user_id=user_id,
    )
    return ids


def create(session: Session, *, data: DefectCreate, actor: Actor) -> Defect:
    """A finding an inspector reports by hand (no job measured it)."""
    inspection = session.get(Inspection, data.inspection_id)
    if inspection is None or inspection.deleted_at is not None:
        raise Problem(422, f"inspection_id: there is no inspection with id {data.inspection_id}.")
    norm = math.sqrt(sum(c * c for c in data.normal))
    if norm < 1e-9:
        raise Problem(422, "normal: must not be the zero vector.")
    finding = NewDefect(
        type=data.type,
        location_mm=tuple(data.location_mm),
        normal=tuple(c / norm for c in data.normal),
        value_mm=data.value_mm,
        tolerance_mm=data.tolerance_mm,
        extent_mm=data.extent_mm,
        severity=data.severity,
        confidence=data.confidence,
    )
    defect_id = record_defect(
        session, finding, inspection_id=data.inspection_id, source="manual", user_id=actor.id
    )
    defect = session.get(Defect, defect_id)
    if data.note.strip():
        defect.notes = [_note(actor, data.note)]
    audit(
        session,
        actor,
        "report",
        entity="defect",
        entity_id=defect.id,
        inspection_id=defect.inspection_id,
        after={
            "type": defect.type,
            "severity": defect.severity,
            "status": "open",
            **({"note": data.note.strip()} if data.note.strip() else {}),
        },
    )
    return defect


def _note(actor: Actor, text: str) -> dict:
    return {
        "user_id": actor.id,
        "username": actor.username,
        "text": text.strip(),
        "at": utcnow().isoformat(timespec="seconds"),
    }


def annotate(session: Session, *, defect_id: int, text: str, actor: Actor) -> Defect:
    """Add a note to a finding (any: measured or reported by hand): kept with it, synced to
    the headsets, audited."""
    defect = get(session, defect_id=defect_id)
    note = _note(actor, text)
    defect.notes = [*(defect.notes or []), note]
    record_update(session, "defect", defect, user_id=actor.id)
    audit(
        session,
        actor,
        "annotate",
        entity="defect",
        entity_id=defect_id,
        inspection_id=defect.inspection_id,
        after={"note": note["text"]},
    )
    session.flush()
    return defect


def set_status(
    session: Session, *, defect_id: int, status: str, reason: str, actor: Actor, role: str
) -> Defect:
    """Resolve, dismiss or reopen a defect, recording who and why. Dismissing needs a
    reason; dismissing a critical defect is for the inspection's owner or an admin."""
    defect = get(session, defect_id=defect_id)
    if status == defect.status:
        return defect
    reason = reason.strip()
    if status == "dismissed" and not reason:
        raise Problem(422, "reason: say why the defect is dismissed (kept in the audit log).")
    if status == "dismissed" and defect.severity == "critical" and role != "admin":
        owner = session.scalar(
            select(Inspection.created_by).where(Inspection.id == defect.inspection_id)
        )
        if owner != actor.id:
            raise Problem(
                403,
                f"Defect {defect_id} is critical: only the inspection's owner or an admin may "
                "dismiss it.",
            )
    before = {"status": defect.status, "status_by": defect.status_by}
    defect.status, defect.status_by, defect.status_reason = status, actor.id, reason
    record_update(session, "defect", defect, user_id=actor.id)
    audit(
        session,
        actor,
        "set_status",
        entity="defect",
        entity_id=defect_id,
        inspection_id=defect.inspection_id,
        before=before,
        after={"status": status, "status_by": actor.id},
        reason=reason,
    )
    session.flush()
    return defect


def history(session: Session, *, defect_id: int) -> DefectHistoryOut:
    """The line of findings ``defect_id`` belongs to, with every judgment revision."""
    defect = get(session, defect_id=defect_id)
    lineage = defect.lineage_id or defect.id
    steps = session.execute(
        select(Defect, Run.name)
        .outerjoin(Run, Run.id == Defect.run_id)
        .where(
            or_(Defect.lineage_id == lineage, Defect.id == lineage),
            Defect.inspection_id == defect.inspection_id,
        )
        .order_by(Defect.id)
    ).all()
    ids = [d.id for d, _ in steps]
    revisions = session.execute(
        select(JudgmentRevision, User.username, Defect.run_id)
        .join(User, User.id == JudgmentRevision.user_id)
        .join(Defect, Defect.id == JudgmentRevision.defect_id)
        .where(JudgmentRevision.defect_id.in_(ids))
        .order_by(JudgmentRevision.created_at, JudgmentRevision.id)
    ).all()
    seen: set[tuple] = set()  # a carried revision is the same revision: listed once
    judgments = []
    for revision, username, run_id in revisions:
        judged_on = revision.judged_on_run_id or run_id
        key = (revision.user_id, revision.revision, judged_on, revision.created_at)
        if key in seen:
            continue
        seen.add(key)
        judgments.append(
            {
                "user_id": revision.user_id,
                "username": username,
                "defect_id": revision.defect_id if revision.judged_on_run_id is None else None,
                "judged_on_run_id": judged_on,
                "revision": revision.revision,
                "verdict": revision.verdict,
                "new_type": revision.new_type,
                "comment": revision.comment,
                "created_at": revision.created_at.isoformat(),
            }
        )
    current = [d.id for d, _ in steps if d.ended is None]
    return DefectHistoryOut(
        defect_id=defect_id,
        lineage_id=lineage,
        current_id=current[-1] if current else None,
        steps=[
            LineageStep.model_validate(d).model_copy(update={"run_name": name}) for d, name in steps
        ],
        judgments=judgments,
    )
