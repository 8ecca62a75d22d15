"""The feedback loop: reviewers' verdicts per type and limit, and the limit suggested."""

from __future__ import annotations

import pytest
from sqlalchemy import insert, select

from supervisor.feedback.service import Row, suggest
from supervisor.models import Defect
from tests.conftest import auth


def _defects(runtime, inspection: int, rows: list[tuple[str, float, float, str]]) -> list[int]:
    """(type, value, tolerance, severity) rows as a measuring job stores them."""
    with runtime.db.write() as session:
        session.execute(
            insert(Defect),
            [
                {
                    "inspection_id": inspection,
                    "type": kind,
                    "status": "open",
                    "value_mm": value,
                    "tolerance_mm": tolerance,
                    "measurements": {"value": value, "tolerance": tolerance, "unit": "mm"},
                    "location_mm": [0.0, 0.0, 0.0],
                    "normal": [0.0, 0.0, 1.0],
                    "severity": severity,
                    "source": "job",
                }
                for kind, value, tolerance, severity in rows
            ],
        )
        return list(session.scalars(select(Defect.id).order_by(Defect.id)))


def test_feedback_counts_verdicts_and_moves_limits(client, tokens, runtime):
    inspector = auth(tokens["inspector"])
    inspection = client.post(
        "/api/v1/inspections",
        json={
            "title": "t",
            "area": "cabin",
            "tolerances": {"gap_mm": {"min": 0.5, "max": 1.5}, "step_mm": {"max": 0.5}},
        },
        headers=inspector,
    ).json()["id"]
    ids = _defects(
        runtime,
        inspection,
        [
            ("step", 0.52, 0.5, "minor"),
            ("step", -0.55, 0.5, "minor"),
            ("step", 0.8, 0.5, "major"),
            ("step", 0.9, 0.5, "major"),
            ("gap", 1.4, 1.5, "info"),  # within tolerance, but reviewers see a defect
            ("gap", 1.6, 1.5, "minor"),
            ("gap", 1.7, 1.5, "minor"),
            ("gap", 0.3, 0.5, "major"),  # too narrow: the lower limit
            ("dent", 0.4, 0.3, "minor"),
        ],
    )
    verdicts = ["rejected", "rejected", "confirmed", "confirmed"]
    verdicts += ["rejected", "confirmed", "confirmed", "confirmed", "confirmed"]
    for voter in ("inspector", "inspector2", "admin"):
        for defect, verdict in zip(ids, verdicts, strict=True):
            if voter == "admin" and defect == ids[1]:
                verdict = "uncertain"  # two of three still reject it
            answer = client.put(
                f"/api/v1/defects/{defect}/judgments/me",
                json={"verdict": verdict},
                headers=auth(tokens[voter]),
            )
            assert answer.status_code == 200
    out = client.get(
        "/api/v1/feedback", params={"inspection": inspection}, headers=auth(tokens["viewer"])
    ).json()
    groups = {(g["type"], g["bound"], g["tolerance"]): g for g in out["groups"]}
    step = groups[("step", "max", 0.5)]
    assert (step["flagged"], step["reviewed"], step["confirmed"], step["rejected"]) == (4, 4, 2, 2)
    assert step["rejected_share"] == 0.5
    assert step["suggestion"]["action"] == "raise" and step["suggestion"]["tolerance"] == 0.55
    gap = groups[("gap", "max", 1.5)]
    assert (gap["flagged"], gap["in_tolerance"], gap["missed"]) == (2, 1, 1)
    assert gap["suggestion"] == {
        "action": "lower",
        "tolerance": 1.39,
        "reason": gap["suggestion"]["reason"],
    }
    narrow = groups[("gap", "min", 0.5)]
    assert narrow["confirmed"] == 1 and narrow["suggestion"]["action"] == "keep"
    assert "at least 3" in narrow["suggestion"]["reason"]
    assert out["suggested_tolerances"] == {
        "gap_mm": {"min": 0.5, "max": 1.39},
        "step_mm": {"max": 0.55},
    }
    created = client.post(
        "/api/v1/inspections",
        json={"title": "next", "area": "cabin", "tolerances": out["suggested_tolerances"]},
        headers=inspector,
    )
    assert created.status_code == 201
    assert (
        client.get("/api/v1/feedback", params={"inspection": 999}, headers=inspector).status_code
        == 404
    )


def _rows(values_outcomes, *, flagged=True, bound="max"):
    return [Row("gap", bound, 1.0, "mm", v, flagged, o) for v, o in values_outcomes]


@pytest.mark.parametrize(
    "rows, action, tolerance",
    [
        # a false alarm at 1.043 below the confirmed 1.2: raise to pass it, on 0.01 mm
        (_rows([(1.043, "rejected"), (1.2, "confirmed"), (1.3, "confirmed")]), "raise", 1.05),
        # the false alarm is above a confirmed finding: raising would pass a defect
        (_rows([(1.3, "rejected"), (1.2, "confirmed"), (1.25, "confirmed")]), "keep", 1.0),
        # closer than the resolution: nothing to gain
        (_rows([(1.201, "rejected"), (1.205, "confirmed"), (1.3, "confirmed")]), "keep", 1.0),
        # all rejected: raise past the largest
        (_rows([(1.1, "rejected"), (1.15, "rejected"), (1.31, "rejected")]), "raise", 1.31),
        # uncertain or unjudged rows are no evidence
        (_rows([(1.1, "rejected"), (1.2, "uncertain"), (1.3, None)]), "keep", 1.0),
    ],
)
def test_suggestion_rules(rows, action, tolerance):
    suggestion = suggest(rows, tolerance=1.0, bound="max", unit="mm", min_reviews=3)
    assert (suggestion.action, suggestion.tolerance) == (action, tolerance)


def test_a_miss_wins_over_false_alarms():
    rows = _rows([(1.1, "rejected"), (1.2, "confirmed"), (1.3, "confirmed")])
    rows += _rows([(0.874, "rejected")], flagged=False)
    suggestion = suggest(rows, tolerance=1.0, bound="max", unit="mm", min_reviews=3)
    assert (suggestion.action, suggestion.tolerance) == ("lower", 0.87)
