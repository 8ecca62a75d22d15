from __future__ import annotations

import math

from sqlalchemy.orm import Session

from supervisor.changes import add_created, record_update
from supervisor.defects.schemas import DefectCreate, DefectOut
from supervisor.judgments.consensus import consensus_for
from supervisor.models import Defect, Inspection
from supervisor.problems import Problem, not_found

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
    add_created(session, "defect", defect, user_id)
    return defect


def set_status(session: Session, *, defect_id: int, status: str, user_id: int) -> Defect:
    defect = get(session, defect_id=defect_id)
    defect.status = status
    record_update(session, "defect", defect, user_id=user_id)
    session.flush()
    return defect
