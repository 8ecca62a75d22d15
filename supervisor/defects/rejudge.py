"""Findings follow their inspection's tolerances: when the tolerances change, each finding a
measurement stored is judged again against the new limits, as the measurement judged it
(``contract.tolerances.judge``), in the same transaction — its limit, severity, tolerance
state (out, within or uncertain, where it was measured with its 1σ) and, for a gap, the
end of its range it is judged by (and where that end is); every change in the change log, so every client sees it. A
finding that cannot be judged without measuring again (a gap stored before its seam's range
was kept) is marked stale with the reason."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from contract.tolerances import Tolerances, advice, judge, limits_of
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
        measurements = dict(defect.measurements or {})
        value = measurements.get("value", defect.value_mm)
        if value is None:
            continue
        sigma = measurements.get("sigma_mm")
        judged = judge(defect.type, value, limits, measurements.get("gap_range_mm"), sigma)
        if judged is None:
            if measurements.get("stale") == STALE:
                continue
            measurements["stale"] = STALE
        else:
            measurements.pop("stale", None)
            if judged.value != measurements.get("value") and "gap_range_at_mm" in measurements:
                # judged by the other end of its range now: the finding is where that end is
                ends = measurements["gap_range_mm"]
                defect.location_mm = measurements["gap_range_at_mm"][ends.index(judged.value)]
                measurements.pop("along_mm", None)  # measured from the seam's start for the old end
            measurements |= {"value": judged.value, "tolerance": judged.limit}
            if sigma is not None:  # measured with its 1σ: out, within or uncertain
                measurements["tolerance_state"] = judged.state
                measurements.pop("advice", None)
                if judged.state == "uncertain":
                    size = abs(judged.value) if defect.type == "step" else judged.value
                    spacing = measurements.get("spacing_mm")
                    measurements["advice"] = advice(
                        size, judged.limit, sigma, spacing, bool(measurements.get("one_phase"))
                    )
            if measurements.get("unit", "mm") == "mm":
                defect.value_mm, defect.tolerance_mm = judged.value, judged.limit
            if judged.severity == defect.severity and measurements == defect.measurements:
                continue
            defect.severity = judged.severity
        defect.measurements = measurements
        record_update(session, "defect", defect, user_id=user_id)
        changed += 1
    return changed
