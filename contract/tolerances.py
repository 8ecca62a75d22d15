"""An inspection's acceptance limits: one model for the API, CONFIG.json, the job
context and ``measure``.

The document (``Tolerances``) is what an inspection's ``tolerances`` and CONFIG.json hold;
``Limits`` is the flat view ``measure`` judges by, every limit filled (defaults where the
document is silent); ``FIELDS`` says where each finding type's limit lives in both.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

TOLERANCE_MAX_MM = 1000.0
"""No acceptance limit is wider than a metre."""
Limit = Annotated[float, Field(gt=0, le=TOLERANCE_MAX_MM)]


@dataclass(frozen=True)
class Limits:
    gap_min_mm: float = 0.5
    gap_max_mm: float = 3.0
    step_max_mm: float = 0.5
    parallelism_max_mm: float = 0.5
    mismatch_max_mm: float = 0.5
    dent_depth_mm: float = 0.2
    """Also the limit for bumps (their height)."""
    scratch_depth_mm: float = 0.1
    color_delta_e: float = 3.0
    profile_min_mm: float = -0.5
    profile_max_mm: float = 0.5
    """A surface's deviation from its nominal must lie in [min, max]."""
    profile_regions: tuple[tuple[str, float, float], ...] = ()
    """Regions of the nominal with their own (name, min, max)."""

    def profile_band(self, region: str | None) -> tuple[float, float]:
        """(min, max) deviation accepted in ``region`` (the part's band where it has none)."""
        own = {name: (low, high) for name, low, high in self.profile_regions}
        return own.get(region or "", (self.profile_min_mm, self.profile_max_mm))


class _Strict(BaseModel):
    """Unknown keys and numbers that are not finite are refused."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class RangeMm(_Strict):
    """A gap's acceptable range; a side not given takes its default (``Limits``)."""

    min: float | None = Field(None, ge=0, le=TOLERANCE_MAX_MM)
    max: Limit | None = None

    @model_validator(mode="after")
    def _ordered(self) -> RangeMm:
        low = Limits.gap_min_mm if self.min is None else self.min
        high = Limits.gap_max_mm if self.max is None else self.max
        if low >= high:
            said = "the default " if self.min is None or self.max is None else ""
            raise ValueError(f"min ({low:g}) must be below max ({high:g}) ({said}range)")
        return self


class LimitMm(_Strict):
    max: Limit


class SurfaceTolerances(_Strict):
    dent_depth_mm: Limit | None = Field(None, description="Deepest acceptable dent/bump.")
    scratch_depth_mm: Limit | None = Field(None, description="Deepest acceptable scratch.")
    color_delta_e: float | None = Field(
        None, gt=0, le=100, description="Largest acceptable CIE ΔE."
    )


class ProfileMm(_Strict):
    """A surface-profile band: ``{"max": m}`` is ±m, ``{"min": a, "max": b}`` is [a, b]
    (a ≤ 0 ≤ b: the nominal itself is in tolerance)."""

    min: float | None = Field(None, ge=-TOLERANCE_MAX_MM, le=0)
    max: float = Field(..., ge=0, le=TOLERANCE_MAX_MM)

    @model_validator(mode="after")
    def _wide(self) -> ProfileMm:
        if (-self.max if self.min is None else self.min) >= self.max:
            raise ValueError("a profile band must be wider than nothing: min < max")
        return self

    def band(self) -> tuple[float, float]:
        return (-self.max if self.min is None else self.min), self.max


class ProfileTolerances(ProfileMm):
    """The part's profile band, and regions of its nominal (named in the file: STL solids,
    OBJ groups, glTF meshes, STEP faces) with their own."""

    max: float = Field(Limits.profile_max_mm, ge=0, le=TOLERANCE_MAX_MM)
    regions: dict[str, ProfileMm] | None = None


class Tolerances(_Strict):
    """Acceptance limits; a measurement outside them becomes a defect."""

    gap_mm: RangeMm | None = None
    step_mm: LimitMm | None = None
    parallelism_mm: LimitMm | None = None
    mismatch_mm: LimitMm | None = None
    surface: SurfaceTolerances | None = None
    profile_mm: ProfileTolerances | None = None


FIELDS: dict[tuple[str, str], tuple[str, str, str]] = {
    ("gap", "min"): ("gap_mm", "min", "gap_min_mm"),
    ("gap", "max"): ("gap_mm", "max", "gap_max_mm"),
    ("step", "max"): ("step_mm", "max", "step_max_mm"),
    ("parallelism", "max"): ("parallelism_mm", "max", "parallelism_max_mm"),
    ("mismatch", "max"): ("mismatch_mm", "max", "mismatch_max_mm"),
    ("dent", "max"): ("surface", "dent_depth_mm", "dent_depth_mm"),
    ("bump", "max"): ("surface", "dent_depth_mm", "dent_depth_mm"),
    ("scratch", "max"): ("surface", "scratch_depth_mm", "scratch_depth_mm"),
    ("color", "max"): ("surface", "color_delta_e", "color_delta_e"),
    ("deviation", "min"): ("profile_mm", "min", "profile_min_mm"),
    ("deviation", "max"): ("profile_mm", "max", "profile_max_mm"),
}
"""(finding type, "min" or "max") → (section, key) in the document, field of ``Limits``."""


def upper_limit(limits: Limits, finding_type: str) -> float:
    """The largest acceptable value of a finding of this type (any but a gap's range)."""
    return getattr(limits, FIELDS[(finding_type, "max")][2])


def limits_of(tolerances: Tolerances) -> Limits:
    """The flat limits: the document's, and the defaults where it is silent."""
    document = tolerances.model_dump(exclude_none=True)
    given = {
        field: document[section][key]
        for section, key, field in FIELDS.values()
        if key in document.get(section, {})
    }
    profile = tolerances.profile_mm
    if profile is not None:
        low, high = profile.band()
        regions = tuple((name, *band.band()) for name, band in (profile.regions or {}).items())
        given |= {"profile_min_mm": low, "profile_max_mm": high, "profile_regions": regions}
    return replace(Limits(), **given)


def merge_tolerances(stored: dict, changes: dict | None) -> dict:
    """``stored`` (a tolerances document) with ``changes`` made to it: a limit not named
    keeps its value, a limit given takes it, a limit (or a section) given as None goes back
    to its default; ``changes`` None: every limit back to its default. Not validated: the
    caller checks the result (a gap's range may only be ordered once merged)."""
    if changes is None:
        return {}
    merged = {section: dict(values) for section, values in stored.items() if values}
    for section, given in changes.items():
        if given is None:
            merged.pop(section, None)
            continue
        values = merged.setdefault(section, {})
        for key, value in given.items():
            if value is None:
                values.pop(key, None)
            else:
                values[key] = value
        if not values:
            del merged[section]
    return merged


def tolerances_of(limits: Limits) -> Tolerances:
    """The document that gives every one of ``limits``."""
    document: dict = {}
    for section, key, field in FIELDS.values():
        document.setdefault(section, {})[key] = getattr(limits, field)
    if limits.profile_regions:
        document["profile_mm"]["regions"] = {
            name: {"min": low, "max": high} for name, low, high in limits.profile_regions
        }
    return Tolerances.model_validate(document)


def severity(value: float, limit: float, *, above: bool) -> str:
    """info inside the limit; beyond it minor (< 25 % of the limit), major (< 100 %),
    critical."""
    excess = value - limit if above else limit - value
    if excess <= 0:
        return "info"
    ratio = excess / max(limit, 0.1)
    return "minor" if ratio < 0.25 else "major" if ratio < 1.0 else "critical"


ToleranceState = Literal["out", "within", "uncertain"]
"""A measured finding against its limit, given its 1σ: ``out`` of tolerance only when it
lies beyond the limit by 2σ or more, ``within`` only when inside it by 2σ or more,
``uncertain`` between (``tolerance_state``)."""
DECISION_SIGMAS = 2.0


def tolerance_state(value: float, limit: float, sigma_mm: float | None, *, above: bool) -> str:
    """``out``, ``within`` or ``uncertain`` (``ToleranceState``) of ``value`` against
    ``limit`` (an upper limit if ``above``, else a lower one), its 1σ ``sigma_mm`` (None:
    judged by the value alone, as a finding without an uncertainty is)."""
    beyond = value > limit if above else value < limit
    if sigma_mm is not None and abs(value - limit) < DECISION_SIGMAS * sigma_mm:
        return "uncertain"
    return "out" if beyond else "within"


def advice(
    value: float,
    limit: float,
    sigma_mm: float,
    spacing_mm: float | None,
    one_phase: bool = False,
) -> str:
    """What would decide an uncertain finding: its 1σ must shrink to half its distance
    from the limit; a corner's σ shrinks with the scan's spacing, so the spacing that
    would give it (where the cloud's spacing is known and that spacing is one a scanner
    reaches, ≥ 0.02 mm) — or, where every profile sampled the seam's edges at one place
    (``one_phase``: scan lines exactly along or across the seam), scan lines turned a few
    degrees to it, whose profiles together sample an edge finely."""
    distance = abs(value - limit)
    needed = distance / DECISION_SIGMAS
    turn = (
        "; or with the scan lines turned 5–15° to the seam (its profiles all sampled the "
        "edges at one place)"
        if one_phase
        else ""
    )
    if spacing_mm is not None and sigma_mm > 0:
        finer = spacing_mm * needed / sigma_mm
        if finer >= 0.02:
            return (
                f"{distance:.3f} mm from its limit with 1σ {sigma_mm:.3f} mm: re-scan at "
                f"≤ {max(0.02, 0.01 * int(finer * 100)):.2f} mm spacing (now "
                f"{spacing_mm:.2f} mm){turn} to decide"
            )
    return (
        f"{distance:.3f} mm from its limit with 1σ {sigma_mm:.3f} mm: too close for a scan to "
        "decide; judge it by hand (a feeler gauge)"
    )


@dataclass(frozen=True)
class Judged:
    value: float
    """The value judged (a gap: the widest or the narrowest of its seam)."""
    limit: float
    severity: str
    state: str = "out"
    """``tolerance_state`` of the value, given the finding's σ (``within`` or ``out`` by
    the value alone when it has none)."""


def judge(
    finding_type: str,
    value: float,
    limits: Limits,
    gap_range_mm: tuple[float, float] | None = None,
    sigma_mm: float | None = None,
    region: str | None = None,
) -> Judged | None:
    """A stored finding judged against ``limits`` as ``measure`` judges it: a step by its
    size either way, a gap by the range of its seam's gaps (``gap_range_mm``: the narrowest
    and the widest) — the widest against the maximum unless only the narrowest is out —
    anything else against its upper limit; with its 1σ ``sigma_mm``, its
    ``tolerance_state`` too. A deviation (signed) against its ``region``'s profile band,
    the side it lies on. None for a gap stored without its range: it cannot be judged
    again without measuring."""
    if finding_type == "deviation":
        low, high = limits.profile_band(region)
        limit, above = (high, True) if value >= 0 else (low, False)
        return Judged(
            value,
            limit,
            severity(abs(value), abs(limit), above=True),
            tolerance_state(value, limit, sigma_mm, above=above),
        )
    if finding_type == "gap":
        if gap_range_mm is None:
            return None
        narrowest, widest = gap_range_mm
        ends = ((widest, limits.gap_max_mm, True), (narrowest, limits.gap_min_mm, False))
        states = [tolerance_state(v, limit, sigma_mm, above=a) for v, limit, a in ends]
        # The end out of tolerance, else the uncertain one, else the widest (ties: widest).
        end = next(
            i for state in ("out", "uncertain", "within") for i in (0, 1) if states[i] == state
        )
        value, limit, above = ends[end]
        return Judged(value, limit, severity(value, limit, above=above), states[end])
    limit = upper_limit(limits, finding_type)
    size = abs(value) if finding_type == "step" else value
    return Judged(
        value,
        limit,
        severity(size, limit, above=True),
        tolerance_state(size, limit, sigma_mm, above=True),
    )


def limit_text(finding_type: str, limits: Limits) -> str:
    """A finding type's acceptable values, read one way everywhere (CLI, demo, dashboard):
    both ends of a gap's range, a step's size either way, the others' upper limit."""
    if finding_type == "gap":
        return f"{limits.gap_min_mm:.2f}–{limits.gap_max_mm:.2f} mm"
    if finding_type == "deviation":
        return f"{limits.profile_min_mm:+.2f} … {limits.profile_max_mm:+.2f} mm"
    limit = upper_limit(limits, finding_type)
    if finding_type == "color":
        return f"≤ {limit:.1f} ΔE"
    return f"|step| ≤ {limit:.2f} mm" if finding_type == "step" else f"≤ {limit:.2f} mm"


def sign_text(finding_type: str, value: float, panels: list[int] | None) -> str:
    """What a signed value means: a step of a seam between panels a and b is b's top over
    a's ("P1 below P0" when negative); "" for the unsigned."""
    if finding_type != "step" or not panels or value == 0:
        return ""
    a, b = panels
    return f"P{b} {'above' if value > 0 else 'below'} P{a}"


def finding_line(finding_type: str, value: float, panels: list[int] | None, limits: Limits) -> str:
    """ "step       -0.768 mm (P1 below P0; limits |step| ≤ 0.50 mm)": a finding's value,
    what its sign means and its limits, as the CLI and the demo print it."""
    unit = "ΔE" if finding_type == "color" else "mm"
    sign = sign_text(finding_type, value, panels)
    return (
        f"{finding_type:<11} {value:>8.3f} {unit} "
        f"({sign + '; ' if sign else ''}limits {limit_text(finding_type, limits)})"
    )
