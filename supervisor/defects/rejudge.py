"""Findings follow their inspection's tolerances: when the tolerances change, each finding a
measurement stored is judged again against the new limits, as the measurement judged it
(``contract.tolerances.judge``), in the same transaction — its limit, severity, tolerance
state (out, within or uncertain, where it was measured with its 1σ) and, for a gap, the
end of its range it is judged by (and where that end is); every change in the change log, so every client sees it. A
finding that cannot be judged without measuring again (a gap stored before its seam's range
was kept) is marked stale with the reason. Its measurements are read and written as their
typed model (``contract.findings``)."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from contract.findings import (
    DeviationMeasurements,
    FindingMeasurements,
    SeamMeasurements,
    measurements_of,
    revised,
    stored,
)
from contract.tolerances import Judged, Limits, Tolerances, advice, judge, limits_of
from supervisor.changes import record_update
from supervisor.models import Defect, Inspection

STALE = "measured before vista kept what a gap is judged on: re-run the measurement to judge it against the new tolerances"


def rejudge_findings(session: Session, inspection: Inspection, *, user_id: int | None) -> int:
    """Judge the inspection's measured findings against its tolerances now; the number
    whose judgment changed (or that turned stale)."""
    limits = limits_of(Tolerances.model_validate(inspection.tolerances or {}))
    changed = 0
    for defect in session.scalars(
        select(Defect).where(Defect.inspection_id == inspection.id, Defect.source == "job")
    ):
        if _rejudged(defect, limits):
            record_update(session, "defect", defect, user_id=user_id)
            changed += 1
    return changed


def _rejudged(defect: Defect, limits: Limits) -> bool:
    """Judge one stored finding again, in place; whether anything about it changed."""
    found = measurements_of(defect.type, defect.measurements)
    value = defect.value_mm if found.value is None else found.value
    if value is None:
        return False
    gap_range = found.gap_range_mm if isinstance(found, SeamMeasurements) else None
    region = found.region if isinstance(found, DeviationMeasurements) else None
    judged = judge(defect.type, value, limits, gap_range, found.sigma_mm, region)
    if judged is None:
        if found.stale == STALE:
            return False
        now = revised(found, stale=STALE)
    else:
        now = _judged_again(defect, found, judged)
        if found.unit == "mm":
            defect.value_mm, defect.tolerance_mm = judged.value, judged.limit
        if judged.severity == defect.severity and stored(now) == defect.measurements:
            return False
        defect.severity = judged.severity
    defect.measurements = stored(now)
    return True


def _judged_again(
    defect: Defect, found: FindingMeasurements, judged: Judged
) -> FindingMeasurements:
    """The finding's measurements as ``judged`` now (and its place: a gap judged by the
    other end of its range now is where that end is)."""
    changes: dict = {"stale": None, "value": judged.value, "tolerance": judged.limit}
    if (
        isinstance(found, SeamMeasurements)
        and found.gap_range_mm is not None
        and found.gap_range_at_mm is not None
        and judged.value != found.value
    ):
        ends = found.gap_range_mm
        defect.location_mm = list(found.gap_range_at_mm[ends.index(judged.value)])
        changes["along_mm"] = None  # measured from the seam's start for the old end
    sigma = found.sigma_mm
    if sigma is not None:  # measured with its 1σ: out, within or uncertain
        changes["tolerance_state"] = judged.state
        changes["advice"] = None
        if judged.state == "uncertain":
            size = abs(judged.value) if defect.type == "step" else judged.value
            changes["advice"] = advice(
                size, judged.limit, sigma, found.spacing_mm, bool(found.one_phase)
            )
    return revised(found, **changes)
