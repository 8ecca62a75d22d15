"""A measured finding's ``measurements`` as typed models: what the defects service writes
(``services/defects/measure.py``) and the supervisor reads back (judging it again when the
tolerances change, matching it to a later measurement's, its tolerance state). Lengths in
mm, points ``[x, y, z]`` in the cloud's frame.

One model per family of finding (``MEASUREMENTS``): a seam's gap, step and parallelism,
a junction's mismatch, and each kind of surface defect. A document is the model with only
the fields set (``stored``): a field never set is absent, not null, so the JSON is what it
was before it was typed. Every field may be absent from a stored row (rows measured by
earlier versions lack the newer ones; a finding reported by other means may carry none),
and keys no model names are kept as they are.
"""

from __future__ import annotations

from typing import Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field

from contract.tolerances import ToleranceState
from contract.vocabulary import DefectType

Point = tuple[float, float, float]
Unit = Literal["mm", "delta_e"]
"""A finding's value: millimetres, or CIE76 ΔE for a colour patch."""


class _View(BaseModel):
    """Part of a stored finding's measurements, for reading: keys it does not name are
    ignored (cheap for every finding listed or synced), so it is never stored back."""

    model_config = ConfigDict(extra="ignore")


class Reading(_View):
    """A stored finding's value, unit and limit: kept in its measurements, where a colour's
    ΔE can live (the row's millimetre columns cannot hold it)."""

    value: float | None = Field(None, description="The value judged, in ``unit``.")
    unit: Unit = Field("mm", description="The value's and the limit's unit.")
    tolerance: float | None = Field(None, description="The limit it was judged against.")


class State(_View):
    tolerance_state: ToleranceState | None = Field(
        None,
        description="out, within or uncertain against the limit, given the 1σ "
        "(``contract.tolerances.tolerance_state``); absent: judged by its severity alone.",
    )


class FindingMeasurements(State, Reading):
    """How a finding was judged, whatever its family: the reading, its state, and for a
    seam's or a junction's finding (measured with its 1σ) what would decide it when
    uncertain."""

    model_config = ConfigDict(extra="allow")

    sigma_mm: float | None = Field(
        None, description="1σ of the value (surface findings have none)."
    )
    spacing_mm: float | None = Field(None, description="The cloud's point spacing.")
    one_phase: bool | None = Field(
        None,
        description="Set (true) where every profile sampled the seam's edges at one place: "
        "scan lines turned to the seam would decide it.",
    )
    advice: str | None = Field(None, description="What would decide an uncertain finding.")
    stale: str | None = Field(
        None, description="Why it cannot be judged again without measuring again."
    )


class Stats(BaseModel):
    """Over a seam's measured sections (mm)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    min: float
    mean: float
    max: float


class SeamMeasurements(FindingMeasurements):
    """A seam's gap, step or parallelism: the seam's profile, and for a gap what it is
    judged on (the ends of its range, and where they lie)."""

    seam: int | None = Field(None, description="The seam's id in the measurement.")
    panels: tuple[int, int] | None = Field(
        None, description="(a, b): the step is b's top over a's."
    )
    gap_mm: Stats | None = Field(None, description="Null where the seam is unmeasured.")
    step_mm: Stats | None = None
    parallelism_mm: float | None = None
    length_mm: float | None = Field(None, description="The seam's length.")
    unmeasured_sections: int | None = None
    gap_range_mm: tuple[float, float] | None = Field(
        None, description="A gap's narrowest and widest judged value along its seam."
    )
    gap_range_at_mm: tuple[Point, Point] | None = Field(
        None, description="Where the narrowest and the widest lie."
    )
    along_mm: float | None = Field(
        None, description="Where the finding lies along its seam, from the seam's start."
    )
    seam_mm: tuple[Point, Point] | None = Field(None, description="The seam's start and end.")


class JunctionMeasurements(FindingMeasurements):
    """A junction's mismatch: the gaps of the seams that meet there."""

    junction: int | None = Field(None, description="The junction's id in the measurement.")
    seams: list[int] | None = Field(None, description="The seams meeting there.")
    gaps_mm: list[float] | None = Field(None, description="Each seam's gap at the junction.")


class SurfaceMeasurements(FindingMeasurements):
    """A defect on a panel's top."""

    panel: int | None = Field(None, description="The panel's id in the measurement.")


class DentMeasurements(SurfaceMeasurements):
    """A dent (below the surface) or a bump (above it)."""

    depth_mm: float | None = Field(None, description="Largest deviation from the surface.")
    diameter_mm: float | None = Field(None, description="Of the circle of the same area.")


class ScratchMeasurements(SurfaceMeasurements):
    depth_mm: float | None = Field(None, description="Below the smoothed surface.")
    length_mm: float | None = None
    width_mm: float | None = None
    direction_uv: tuple[float, float] | None = Field(
        None, description="Unit direction along it in the measurement's surface frame."
    )


class ColorMeasurements(SurfaceMeasurements):
    delta_e: float | None = Field(None, description="Mean CIE76 ΔE of the patch's core.")
    peak_delta_e: float | None = None
    area_mm2: float | None = None


class DeviationMeasurements(FindingMeasurements):
    """An area of the surface off its nominal beyond the profile band: ``value`` is its
    peak signed deviation (positive: outside the nominal's material)."""

    region: str | None = Field(None, description="The nominal's region it lies in.")
    mean_mm: float | None = Field(None, description="Mean deviation over its area.")
    area_mm2: float | None = None
    points: int | None = Field(None, description="Scan points in it.")
    band_mm: tuple[float, float] | None = Field(
        None, description="The profile band (min, max) it was judged against."
    )


MEASUREMENTS: dict[DefectType, type[FindingMeasurements]] = {
    "gap": SeamMeasurements,
    "step": SeamMeasurements,
    "parallelism": SeamMeasurements,
    "mismatch": JunctionMeasurements,
    "dent": DentMeasurements,
    "bump": DentMeasurements,
    "scratch": ScratchMeasurements,
    "color": ColorMeasurements,
    "deviation": DeviationMeasurements,
}
"""Each finding type's measurements."""

Measurements = TypeVar("Measurements", bound=FindingMeasurements)


def measurements_of(finding_type: str, document: dict | None) -> FindingMeasurements:
    """A stored finding's measurements as its type's model."""
    return MEASUREMENTS[finding_type].model_validate(document or {})


def stored(measurements: FindingMeasurements) -> dict:
    """The JSON document kept: the fields set, and the keys no model names."""
    return measurements.model_dump(mode="json", exclude_unset=True)


def revised(measurements: Measurements, **changes: object) -> Measurements:
    """``measurements`` with ``changes`` made to fields of its model, checked; a field
    changed to None is left out (absent, as in a finding that never had it)."""
    unknown = sorted(set(changes) - set(type(measurements).model_fields))
    if unknown:
        raise TypeError(f"{type(measurements).__name__} has no field {unknown}")
    kept = measurements.model_dump(exclude_unset=True, exclude=set(changes))
    given = {name: value for name, value in changes.items() if value is not None}
    return type(measurements).model_validate(kept | given)


def stored_state(severity: str, document: dict | None) -> ToleranceState:
    """A stored finding's ``tolerance_state``: as measured with its σ, else by its severity
    alone (within for info, out otherwise)."""
    state = State.model_validate(document or {}).tolerance_state
    return state or ("within" if severity == "info" else "out")
