"""How a measurement compares with the simulator's ground truth (truth.json of
``vista defects simulate``): per-section gap and step errors, parallelism and mismatch
errors, out-of-tolerance precision/recall, surface detection recall and false positives."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from contract.tolerances import Limits, upper_limit
from services.defects.measure import MeasureResult, SeamResult
from services.defects.sections import SectionConfig
from services.defects.truth import TrueSeam, Truth

SEAM_MATCH_MM = 10.0
PITCH_MM = SectionConfig.pitch_mm
JUNCTION_MATCH_MM = 15.0
SURFACE_TYPES = ("dent", "bump", "scratch", "color")
GEOMETRIC_TYPES = ("gap", "step", "parallelism", "mismatch")


@dataclass
class Counts:
    true_positive: int = 0
    false_positive: int = 0
    false_negative: int = 0

    @property
    def precision(self) -> float:
        found = self.true_positive + self.false_positive
        return self.true_positive / found if found else 1.0

    @property
    def recall(self) -> float:
        real = self.true_positive + self.false_negative
        return self.true_positive / real if real else 1.0

    def add(self, other: Counts) -> None:
        self.true_positive += other.true_positive
        self.false_positive += other.false_positive
        self.false_negative += other.false_negative


def error_p95(errors: list[float]) -> float | None:
    """95th percentile of |error| (None without any)."""
    return float(np.percentile(np.abs(errors), 95)) if errors else None


def within_2sigma(errors_sigma: list[float]) -> float | None:
    """The share of |error| / σ at 2 or less (None without any)."""
    return float(np.mean(np.asarray(errors_sigma) <= 2.0)) if errors_sigma else None


@dataclass
class Evaluation:
    gap_errors_mm: list[float] = field(default_factory=list)
    """Per measured section: measured − true."""
    step_errors_mm: list[float] = field(default_factory=list)
    parallelism_errors_mm: list[float] = field(default_factory=list)
    mismatch_errors_mm: list[float] = field(default_factory=list)
    gap_errors_sigma: list[float] = field(default_factory=list)
    """Per measured section: |measured − true| over the section's 1σ."""
    seam_end_errors_sigma: list[float] = field(default_factory=list)
    """Per end of a measured seam: |gap line − true gap| there over the seam's 1σ."""
    uncertain_findings: int = 0
    """Findings within 2σ of their limit (counted as found where the truth is out)."""
    sections_total: int = 0
    """Sections of the seams found, and those a seam not found would have had (its length
    over the default pitch): a seam lost with its panels merged is unmeasured too."""
    sections_unmeasured: int = 0
    negative_gaps: int = 0
    """Measured sections with a gap below zero (the panels never overlap here)."""
    unmeasurable_true: int = 0
    """Sections whose truth cannot be seen (a corner in the higher panel's shadow)…"""
    unmeasurable_flagged: int = 0
    """…of which the measurement left unmeasured."""
    edge_models: dict[str, int] = field(default_factory=dict)
    """How often each edge model was chosen for a side of a matched seam."""
    seams_true: int = 0
    seams_found: int = 0
    seams_spurious: int = 0
    junctions_true: int = 0
    junctions_found: int = 0
    geometric: dict[str, Counts] = field(
        default_factory=lambda: {t: Counts() for t in GEOMETRIC_TYPES}
    )
    surface: dict[str, Counts] = field(default_factory=lambda: {t: Counts() for t in SURFACE_TYPES})
    """Detection (any finding, in tolerance or not) of true defects within the recall floor;
    false positives = findings matching no true defect."""
    surface_missed_below_floor: int = 0
    panel_area_m2: float = 0.0
    seconds: float = 0.0

    def add(self, other: Evaluation) -> None:
        for name in (
            "gap_errors_mm",
            "gap_errors_sigma",
            "seam_end_errors_sigma",
            "step_errors_mm",
            "parallelism_errors_mm",
            "mismatch_errors_mm",
        ):
            getattr(self, name).extend(getattr(other, name))
        for name in (
            "uncertain_findings",
            "sections_total",
            "sections_unmeasured",
            "negative_gaps",
            "unmeasurable_true",
            "unmeasurable_flagged",
            "seams_true",
            "seams_found",
            "seams_spurious",
            "junctions_true",
            "junctions_found",
            "surface_missed_below_floor",
            "panel_area_m2",
            "seconds",
        ):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        for table in ("geometric", "surface"):
            for key, counts in getattr(other, table).items():
                getattr(self, table)[key].add(counts)
        for model, n in other.edge_models.items():
            self.edge_models[model] = self.edge_models.get(model, 0) + n

    def summary(self) -> dict:
        def mean(values: list[float]) -> float | None:
            return float(np.mean(values)) if values else None

        false_positives = sum(c.false_positive for c in self.surface.values())
        return {
            "sections": len(self.gap_errors_mm),
            "sections_total": self.sections_total,
            "unmeasured_share": (
                self.sections_unmeasured / self.sections_total if self.sections_total else None
            ),
            "negative_gaps": self.negative_gaps,
            "unmeasurable_flagged_share": (
                self.unmeasurable_flagged / self.unmeasurable_true
                if self.unmeasurable_true
                else None
            ),
            "unmeasurable_sections": self.unmeasurable_true,
            "uncertain_findings": self.uncertain_findings,
            "edge_models": dict(self.edge_models),
            "gap_error_mean_mm": mean(self.gap_errors_mm),
            "gap_error_p95_mm": error_p95(self.gap_errors_mm),
            "gap_error_max_mm": max(np.abs(self.gap_errors_mm), default=None),
            "sections_within_2sigma": within_2sigma(self.gap_errors_sigma),
            "seam_ends_within_2sigma": within_2sigma(self.seam_end_errors_sigma),
            "step_error_mean_mm": mean(self.step_errors_mm),
            "step_error_p95_mm": error_p95(self.step_errors_mm),
            "parallelism_error_max_mm": max(np.abs(self.parallelism_errors_mm), default=None),
            "parallelism_error_p95_mm": error_p95(self.parallelism_errors_mm),
            "mismatch_error_max_mm": max(np.abs(self.mismatch_errors_mm), default=None),
            "mismatch_error_p95_mm": error_p95(self.mismatch_errors_mm),
            "seams": f"{self.seams_found}/{self.seams_true} (+{self.seams_spurious} spurious)",
            "junctions": f"{self.junctions_found}/{self.junctions_true}",
            "geometric": {
                k: {
                    "tp": c.true_positive,
                    "fp": c.false_positive,
                    "fn": c.false_negative,
                    "precision": c.precision,
                    "recall": c.recall,
                }
                for k, c in self.geometric.items()
            },
            "surface": {
                k: {
                    "tp": c.true_positive,
                    "fp": c.false_positive,
                    "fn": c.false_negative,
                    "recall": c.recall,
                }
                for k, c in self.surface.items()
            },
            "surface_missed_below_floor": self.surface_missed_below_floor,
            "surface_false_positives_per_m2": (
                false_positives / self.panel_area_m2 if self.panel_area_m2 else None
            ),
            "panel_area_m2": self.panel_area_m2,
            "seconds_per_m2": self.seconds / self.panel_area_m2 if self.panel_area_m2 else None,
        }


def _match_seam(truth: TrueSeam, seams: list[SeamResult]) -> tuple[SeamResult, float] | None:
    """The measured seam along the true one, and +1/−1 if it runs the same/other way."""
    start, end = np.array(truth.start), np.array(truth.end)
    direction = (end - start) / np.linalg.norm(end - start)
    best = None
    for seam in seams:
        middle = (seam.start + seam.end) / 2
        offset = middle - start
        distance = np.linalg.norm(offset - (offset @ direction) * direction)
        along = offset @ direction
        measured = (seam.end - seam.start) / np.linalg.norm(seam.end - seam.start)
        parallel = abs(measured @ direction) > 0.9
        on_segment = -5 <= along <= np.linalg.norm(end - start) + 5
        if (
            parallel
            and on_segment
            and distance < SEAM_MATCH_MM
            and (best is None or distance < best[2])
        ):
            best = (seam, float(np.sign(measured @ direction)), distance)
    return None if best is None else best[:2]


def _out(kind: str, value: float, t: Limits) -> bool:
    if kind == "gap":
        raise ValueError("gap uses its range")
    return abs(value) > upper_limit(t, kind)


EdgesSeen = Callable[[int, np.ndarray], np.ndarray]
"""(true seam id, (K,) fractions along it) → (K, 2) whether any view saw each side's edge
there (``AssemblyScanner.edges_seen``)."""


END_ALLOWANCE_MM = 15.0
"""Sections stay clear of a seam's ends (its junctions and corners) by up to about this."""


def _sections_not_reached(
    fraction: np.ndarray, segment: np.ndarray, seam_id: int, seen: EdgesSeen | None
) -> int:
    """How many sections the measured seam's (at ``fraction`` of the true seam along
    ``segment``) leave out of the true seam's length: those, every pitch along it, more
    than ``END_ALLOWANCE_MM`` from its ends and more than a pitch from any section, where
    a view saw both edges — a seam found over a part of its length lost the rest (a seam
    found over 28 of its 150 mm counted 4 of 4 sections measured)."""
    length = float(np.linalg.norm(segment))
    along = np.arange(END_ALLOWANCE_MM, length - END_ALLOWANCE_MM, PITCH_MM)
    if not len(along):
        return 0
    at = np.asarray(fraction) * length
    missed = np.ones(len(along), bool)
    if len(at):
        missed = np.abs(np.subtract.outer(along, at)).min(axis=1) > PITCH_MM
    if seen is not None and missed.any():
        missed[missed] = seen(seam_id, along[missed] / length).all(axis=1)
    return int(missed.sum())


def evaluate(
    result: MeasureResult, truth: Truth, tolerances: Limits, *, seen: EdgesSeen | None = None
) -> Evaluation:
    """Compare ``result`` with the truth (``truth.truth_of``); ``seen``
    tells which sections' edges no view saw (their truth cannot be measured)."""
    e = Evaluation(panel_area_m2=result.panel_area_m2, seconds=sum(result.seconds.values()))
    # A finding out of tolerance, or uncertain (shown for a person to decide), is found;
    # only one out of tolerance counts as a false alarm.
    flagged = {(f.type, f.source.get("seam", f.source.get("junction"))) for f in result.defects}
    unsure = {(f.type, f.source.get("seam", f.source.get("junction"))) for f in result.uncertain}
    e.uncertain_findings = len(unsure)
    matched_seams: dict[int, SeamResult] = {}
    for true_seam in truth.seams:
        e.seams_true += 1
        match = _match_seam(true_seam, result.seams)
        start, end = np.array(true_seam.start), np.array(true_seam.end)
        g0, g1 = true_seam.gap_start_mm, true_seam.gap_end_mm
        true_out = {
            "gap": min(g0, g1) < tolerances.gap_min_mm or max(g0, g1) > tolerances.gap_max_mm,
            "step": _out("step", true_seam.step_mm, tolerances),
            "parallelism": _out("parallelism", true_seam.parallelism_mm, tolerances),
        }
        if match is None:
            for kind, out in true_out.items():
                e.geometric[kind].false_negative += int(out)
            lost = int(np.linalg.norm(np.subtract(true_seam.end, true_seam.start)) // PITCH_MM)
            e.sections_total += lost
            e.sections_unmeasured += lost
            continue
        seam, sign = match
        matched_seams[true_seam.id] = seam
        e.seams_found += 1
        segment = end - start
        fraction = (seam.sections_at - start) @ segment / (segment @ segment)
        true_gap = g0 + (g1 - g0) * np.clip(fraction, 0, 1)
        measured = seam.measured
        for edge in seam.edges:
            e.edge_models[edge.model] = e.edge_models.get(edge.model, 0) + 1
        lost = _sections_not_reached(fraction, segment, true_seam.id, seen)
        e.sections_total += len(measured) + lost
        e.sections_unmeasured += int((~measured).sum()) + lost
        e.negative_gaps += int((seam.sections_gap_mm[measured] < 0).sum())
        hidden = np.zeros(len(fraction), bool)
        if seen is not None:
            hidden = ~seen(true_seam.id, np.clip(fraction, 0, 1)).all(axis=1)
        e.unmeasurable_true += int(hidden.sum())
        e.unmeasurable_flagged += int((hidden & ~measured).sum())
        errors = seam.sections_gap_mm[measured] - true_gap[measured]
        e.gap_errors_mm += errors.tolist()
        e.gap_errors_sigma += (
            np.abs(errors) / np.maximum(seam.sections_gap_sigma_mm[measured], 1e-9)
        ).tolist()
        if seam.gap_at_ends_mm is not None:
            ends = np.array([seam.start, seam.end])
            at = np.clip((ends - start) @ segment / (segment @ segment), 0, 1)
            true_ends = g0 + (g1 - g0) * at
            e.seam_end_errors_sigma += [
                abs(m - t) / max(seam.gap_sigma_mm, 1e-9)
                for m, t in zip(seam.gap_at_ends_mm, true_ends, strict=True)
            ]
        has_step = np.isfinite(seam.sections_step_mm)
        e.step_errors_mm += (seam.sections_step_mm[has_step] - sign * true_seam.step_mm).tolist()
        if seam.parallelism_mm is not None:
            e.parallelism_errors_mm.append(seam.parallelism_mm - true_seam.parallelism_mm)
        for kind, out in true_out.items():
            found = (kind, seam.id) in flagged
            counts = e.geometric[kind]
            counts.true_positive += int(out and (found or (kind, seam.id) in unsure))
            counts.false_negative += int(out and not (found or (kind, seam.id) in unsure))
            counts.false_positive += int(found and not out)
    matched_ids = {s.id for s in matched_seams.values()}
    for seam in result.seams:
        if seam.id not in matched_ids:
            e.seams_spurious += 1
            for kind in ("gap", "step", "parallelism"):
                e.geometric[kind].false_positive += int((kind, seam.id) in flagged)
    used_junctions = set()
    for true_junction in truth.junctions:
        e.junctions_true += 1
        out = _out("mismatch", true_junction.mismatch_mm, tolerances)
        at = np.array(true_junction.at)
        near = [
            j for j in result.junctions if np.linalg.norm(j.at[:2] - at[:2]) < JUNCTION_MATCH_MM
        ]
        counts = e.geometric["mismatch"]
        if not near:
            counts.false_negative += int(out)
            continue
        junction = near[0]
        used_junctions.add(junction.id)
        e.junctions_found += 1
        e.mismatch_errors_mm.append(junction.mismatch_mm - true_junction.mismatch_mm)
        found = ("mismatch", junction.id) in flagged
        shown = found or ("mismatch", junction.id) in unsure
        counts.true_positive += int(out and shown)
        counts.false_negative += int(out and not shown)
        counts.false_positive += int(found and not out)
    for junction in result.junctions:
        if junction.id not in used_junctions:
            e.geometric["mismatch"].false_positive += int(("mismatch", junction.id) in flagged)
    _evaluate_surface(e, result, truth)
    return e


def _evaluate_surface(e: Evaluation, result: MeasureResult, truth: Truth) -> None:
    findings = [f for f in result.findings if f.type in SURFACE_TYPES]
    used = np.zeros(len(findings), dtype=bool)
    for defect in truth.defects:
        at = np.array(defect.location)
        reach = max(5.0, 0.5 * defect.size_mm)
        hit = None
        for k, f in enumerate(findings):
            if f.type == defect.type and not used[k] and np.linalg.norm(f.location - at) <= reach:
                hit = k
                break
        if hit is not None:
            used[hit] = True
        if not defect.in_recall_target:
            e.surface_missed_below_floor += int(hit is None)
            continue
        counts = e.surface[defect.type]
        counts.true_positive += int(hit is not None)
        counts.false_negative += int(hit is None)
    for k, f in enumerate(findings):
        if not used[k]:
            e.surface[f.type].false_positive += 1
