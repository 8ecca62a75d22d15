"""The seam between the defects service and the supervisor: a finding's measurements as
typed models (``contract.findings``). Rows stored today, by earlier versions and by other
means read and write back unchanged; a change names fields of its model."""

from __future__ import annotations

import pytest

from contract.findings import (
    ColorMeasurements,
    SeamMeasurements,
    measurements_of,
    revised,
    stored,
    stored_state,
)

GAP = {
    "value": 3.4128,
    "unit": "mm",
    "tolerance": 3.0,
    "seam": 2,
    "panels": [1, 3],
    "gap_mm": {"min": 2.1, "mean": 2.9, "max": 3.5},
    "step_mm": {"min": -0.1, "mean": 0.05, "max": 0.2},
    "parallelism_mm": 1.2,
    "length_mm": 140.2,
    "unmeasured_sections": 0,
    "gap_range_mm": [2.2, 3.4128],
    "gap_range_at_mm": [[0.0, 1.0, 2.0], [100.0, 1.0, 2.0]],
    "sigma_mm": 0.02,
    "tolerance_state": "out",
    "spacing_mm": 0.2,
    "along_mm": 98.5,
    "seam_mm": [[0.0, 1.0, 2.0], [140.0, 1.0, 2.0]],
}


@pytest.mark.parametrize(
    ("finding_type", "document"),
    [
        ("gap", GAP),
        ("step", {**GAP, "gap_mm": None, "parallelism_mm": None, "one_phase": True}),
        ("step", {"value": -0.8, "unit": "mm", "tolerance": 0.5}),  # measured long ago
        ("mismatch", {"junction": 0, "seams": [0, 1, 2], "gaps_mm": [1.0, 1.5, 2.0]}),
        ("color", {"value": 4.1, "unit": "delta_e", "panel": 1, "delta_e": 4.1}),
        ("dent", {"samples": 12, "method": "bench"}),  # keys no model names
        ("scratch", {}),
    ],
)
def test_stored_measurements_read_and_write_back_unchanged(finding_type, document) -> None:
    assert stored(measurements_of(finding_type, document)) == document


def test_the_typed_fields_are_what_the_supervisor_reads() -> None:
    gap = measurements_of("gap", GAP)
    assert isinstance(gap, SeamMeasurements)
    assert gap.gap_range_mm == (2.2, 3.4128) and gap.gap_range_at_mm[1] == (100.0, 1.0, 2.0)
    assert gap.seam_mm[1] == (140.0, 1.0, 2.0) and gap.sigma_mm == 0.02
    colour = measurements_of("color", {"unit": "delta_e", "peak_delta_e": 6.0})
    assert isinstance(colour, ColorMeasurements) and colour.unit == "delta_e"
    assert measurements_of("bump", None).unit == "mm"


def test_a_revision_drops_what_is_set_to_none_and_names_its_fields() -> None:
    gap = measurements_of("gap", {**GAP, "stale": "old", "advice": "re-scan"})
    now = revised(gap, value=2.2, stale=None, along_mm=None, advice=None)
    assert stored(now) == {k: v for k, v in GAP.items() if k != "along_mm"} | {"value": 2.2}
    with pytest.raises(TypeError, match="no field"):
        revised(gap, delta_e=3.0)  # a colour's, not a seam's


def test_the_stored_state_or_the_severity_says_out_within_or_uncertain() -> None:
    assert stored_state("info", {"tolerance_state": "uncertain", "sigma_mm": 0.1}) == "uncertain"
    assert stored_state("info", {}) == "within" and stored_state("minor", None) == "out"
