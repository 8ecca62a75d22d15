"""The feedback loop: what reviewers made of the automatic findings, per defect type and
limit, and the limit to use next time.

Reviewers judge the automatic verdict of a row: on a finding out of tolerance, *confirmed*
means it is a defect and *rejected* a false alarm; on a row kept within tolerance (a seam
measured and found good), *rejected* means the reviewer sees a defect the limit let
through (a miss). A row's outcome is its reviewers' majority; without a firm one
(a tie, or a majority of *uncertain*) it is uncertain.

Suggestions move a limit only as far as the reviewed values justify, on the limit's
resolution (0.01 mm, 0.1 ΔE):
- a miss lowers the limit just below the smallest missed value (missing a defect is worse
  than a false alarm, so this wins over any raise);
- false alarms below every confirmed finding raise the limit just enough to pass the
  largest of them, and never so far that a confirmed finding would pass;
- fewer than ``min_reviews`` reviewed rows keep the limit.
"""

from __future__ import annotations

import copy
import math
from collections import defaultdict
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from contract.tolerances import FIELDS
from supervisor.defects.service import reading
from supervisor.feedback.schemas import FeedbackOut, Suggestion, ToleranceFeedback
from supervisor.inspections.service import live
from supervisor.judgments.consensus import tally, votes_for
from supervisor.models import Defect, Inspection

RESOLUTION = {"mm": 0.01, "delta_e": 0.1}


@dataclass(frozen=True)
class Row:
    """One automatic row as the feedback sees it."""

    type: str
    bound: str
    tolerance: float
    unit: str
    magnitude: float
    """The value in the limit's sense: above ``tolerance`` is out (for ``min`` negated)."""
    flagged: bool
    outcome: str | None
    """The reviewers' majority, ``uncertain`` without a firm one, None if not judged."""


def _outcome(votes: list[tuple[str, str | None, int]]) -> str | None:
    if not votes:
        return None
    majority = tally(votes).majority
    return "uncertain" if majority is None else majority


def _row(defect, votes) -> Row | None:  # noqa: ANN001 - a result row
    read = reading(defect.value_mm, defect.tolerance_mm, defect.measurements)
    value, unit, tolerance = read["value"], read["unit"], read["tolerance"]
    if value is None or tolerance is None:
        return None
    flagged = defect.severity != "info"
    # A gap flagged below its limit is too narrow; rows within tolerance carry the upper
    # limit (the measuring job stores that one for them).
    bound = "min" if defect.type == "gap" and flagged and value < tolerance else "max"
    magnitude = abs(value) if defect.type == "step" else value
    return Row(
        type=defect.type,
        bound=bound,
        tolerance=float(tolerance),
        unit=unit,
        magnitude=-magnitude if bound == "min" else magnitude,
        flagged=flagged,
        outcome=_outcome(votes),
    )


def suggest(
    rows: list[Row], *, tolerance: float, bound: str, unit: str, min_reviews: int
) -> Suggestion:
    """The limit to use next time from one group's reviewed rows (see the module doc)."""
    step = RESOLUTION.get(unit, 0.01)
    limit = -tolerance if bound == "min" else tolerance

    def back(value: float) -> float:
        value = -value if bound == "min" else value
        return round(value, 6)

    confirmed = [r.magnitude for r in rows if r.flagged and r.outcome == "confirmed"]
    rejected = [r.magnitude for r in rows if r.flagged and r.outcome == "rejected"]
    missed = [r.magnitude for r in rows if not r.flagged and r.outcome == "rejected"]
    evidence = sum(r.outcome not in (None, "uncertain") for r in rows)
    if evidence < min_reviews:
        return Suggestion(
            action="keep",
            tolerance=tolerance,
            reason=f"{evidence} reviewed rows; at least {min_reviews} are needed to move it.",
        )
    if missed:
        lowest = min(missed)
        new = math.floor(lowest / step - 1e-9) * step
        if bound == "max":
            new = max(new, step)
        return Suggestion(
            action="lower" if bound == "max" else "raise",
            tolerance=back(new),
            reason=f"{len(missed)} row(s) within tolerance were judged defects (the one "
            f"nearest the limit at {back(lowest):g} {unit}); this limit flags them.",
        )
    ceiling = min(confirmed) if confirmed else math.inf
    false_alarms = [v for v in rejected if v < ceiling]
    if not false_alarms:
        return Suggestion(
            action="keep",
            tolerance=tolerance,
            reason=f"no false alarm below the confirmed findings ({len(confirmed)} confirmed, "
            f"{len(rejected)} rejected).",
        )
    new = math.ceil(max(false_alarms) / step - 1e-9) * step
    if new >= ceiling or new <= limit:
        return Suggestion(
            action="keep",
            tolerance=tolerance,
            reason=f"the false alarms and confirmed findings are closer than {step:g} {unit}.",
        )
    passed = sum(v <= new for v in rejected)
    return Suggestion(
        action="raise" if bound == "max" else "lower",
        tolerance=back(new),
        reason=f"{passed} of {len(rejected)} rejected finding(s) pass this limit; "
        + (
            f"the smallest confirmed one ({back(ceiling):g} {unit}) is still flagged."
            if confirmed
            else "none was confirmed."
        ),
    )


def _group(key: tuple, rows: list[Row], min_reviews: int) -> ToleranceFeedback:
    defect_type, bound, tolerance, unit = key
    flagged = [r for r in rows if r.flagged]
    counts = defaultdict(int)
    for r in flagged:
        counts[r.outcome] += 1
    reviewed = counts["confirmed"] + counts["rejected"] + counts["reclassified"]
    return ToleranceFeedback(
        type=defect_type,
        bound=bound,
        tolerance=tolerance,
        unit=unit,
        flagged=len(flagged),
        in_tolerance=len(rows) - len(flagged),
        reviewed=reviewed,
        confirmed=counts["confirmed"],
        rejected=counts["rejected"],
        reclassified=counts["reclassified"],
        uncertain=counts["uncertain"],
        confirmed_share=counts["confirmed"] / reviewed if reviewed else None,
        rejected_share=counts["rejected"] / reviewed if reviewed else None,
        missed=sum(1 for r in rows if not r.flagged and r.outcome == "rejected"),
        suggestion=suggest(
            rows, tolerance=tolerance, bound=bound, unit=unit, min_reviews=min_reviews
        ),
    )


def _apply(tolerances: dict, groups: list[ToleranceFeedback]) -> dict:
    suggested = copy.deepcopy(tolerances)
    for group in groups:
        if group.suggestion.action == "keep":
            continue
        section, name, _ = FIELDS[(group.type, group.bound)]
        suggested.setdefault(section, {})[name] = group.suggestion.tolerance
    return suggested


def feedback(session: Session, *, inspection_id: int | None, min_reviews: int) -> FeedbackOut:
    query = select(
        Defect.id,
        Defect.type,
        Defect.severity,
        Defect.value_mm,
        Defect.tolerance_mm,
        Defect.measurements,
    ).where(Defect.source == "job", Defect.ended.is_(None), live(Defect.inspection_id))
    if inspection_id is not None:
        query = query.where(Defect.inspection_id == inspection_id)
    defects = session.execute(query).all()
    votes = votes_for(session, (d.id for d in defects))
    grouped: dict[tuple, list[Row]] = defaultdict(list)
    for defect in defects:
        row = _row(defect, votes.get(defect.id, []))
        if row is not None:
            grouped[(row.type, row.bound, row.tolerance, row.unit)].append(row)
    groups = [_group(key, rows, min_reviews) for key, rows in sorted(grouped.items())]
    suggested = None
    if inspection_id is not None:
        inspection = session.get(Inspection, inspection_id)
        suggested = _apply(inspection.tolerances or {}, groups)
    return FeedbackOut(
        inspection_id=inspection_id,
        min_reviews=min_reviews,
        groups=groups,
        suggested_tolerances=suggested,
    )
