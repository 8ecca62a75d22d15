"""RESULT.json and the gap/step profile plot of a measurement."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contract.findings import Stats, stored
from services.defects.config import MeasureConfig, config_document
from services.defects.edges import MODELS
from services.defects.measure import Finding, MeasureResult, PanelResult, SeamResult
from services.defects.sections import EdgeShape
from services.lib.wording import counted

RESULT_FORMAT = "vista.defects/1"


def _point(p: np.ndarray) -> list[float | None]:
    return [_number(v) for v in p]


def _number(value: float | None, digits: int = 4) -> float | None:
    return round(float(value), digits) if value is not None and np.isfinite(value) else None


def finding_document(f: Finding) -> dict:
    return {
        "type": f.type,
        "value": _number(f.value),
        "unit": f.unit,
        "value_mm": _number(f.value) if f.unit == "mm" else None,
        "tolerance": _number(f.tolerance),
        "tolerance_mm": _number(f.tolerance) if f.unit == "mm" else None,
        "location": _point(f.location),
        "normal": _point(f.normal),
        "extent_mm": _number(f.extent_mm, 3),
        "severity": f.severity,
        "confidence": _number(f.confidence, 3),
        "sigma_mm": _number(f.sigma_mm),
        "tolerance_state": f.state or ("out" if f.out_of_tolerance else "within"),
        **f.source,
        "measurements": {
            k: (_number(v) if isinstance(v, float) else v)
            for k, v in stored(f.measurements).items()
        },
    }


def _stats(stats: Stats | None) -> dict | None:
    return None if stats is None else {k: _number(v) for k, v in stats.model_dump().items()}


def _edge(edge: EdgeShape) -> dict:
    document: dict = {"model": edge.model}
    if edge.radius_mm is not None:
        document["radius_mm"] = _number(edge.radius_mm, 3)
    if edge.angle_deg is not None:
        document["angle_deg"] = _number(edge.angle_deg, 2)
    if edge.burr_mm:
        document["burr_mm"] = _number(edge.burr_mm, 3)
    return document


def seam_document(s: SeamResult) -> dict:
    """A seam in RESULT.json: its summary, its edges and every section."""
    sections = []
    for i, at in enumerate(s.sections_at):
        section = {
            "at": _point(at),
            "gap_mm": _number(s.sections_gap_mm[i]),
            "gap_sigma_mm": _number(s.sections_gap_sigma_mm[i]),
            "step_mm": _number(s.sections_step_mm[i]),
            "edges": [MODELS[m] for m in s.sections_models[i]],
            "residual_mm": [_number(r) for r in s.sections_residual_mm[i]],
        }
        if s.sections_unmeasured[i] is not None:
            section["unmeasured"] = s.sections_unmeasured[i]
        sections.append(section)
    return {
        "id": s.id,
        "panels": list(s.panels),
        "start": _point(s.start),
        "end": _point(s.end),
        "length_mm": _number(s.length_mm, 3),
        "unmeasured": s.unmeasured,
        "sections_measured": int(s.measured.sum()),
        "sections_unmeasured": int((~s.measured).sum()),
        "gap_mm": _stats(s.gap_mm),
        "step_mm": _stats(s.step_mm),
        "parallelism_mm": None if s.parallelism_mm is None else _number(s.parallelism_mm),
        "gap_at_ends_mm": None
        if s.gap_at_ends_mm is None
        else [_number(g) for g in s.gap_at_ends_mm],
        "gap_sigma_mm": _number(s.gap_sigma_mm),
        "step_sigma_mm": _number(s.step_sigma_mm),
        "edge_sampling_mm": _number(s.edge_sampling_mm),
        "parallelism_sigma_mm": None
        if s.parallelism_mm is None
        else _number(np.sqrt(2) * s.gap_sigma_mm),
        "edges": [_edge(e) for e in s.edges],
        "noise_mm": _number(s.noise_mm),
        "normal": _point(s.normal),
        "sections": sections,
    }


def panel_document(p: PanelResult) -> dict:
    return {
        "id": p.id,
        "centroid": _point(p.centroid),
        "bounds_mm": {"min": _point(p.bounds_min), "max": _point(p.bounds_max)},
        "normal": _point(p.normal),
        "area_mm2": _number(p.area_mm2, 1),
        "outline": [_point(q) for q in p.outline],
    }


def result_document(result: MeasureResult, config: MeasureConfig) -> dict:
    """RESULT.json: panels, seams, junctions, defects (out of tolerance by 2σ or more),
    the uncertain findings (within 2σ of their limit), the unmeasured seams with why, and
    every finding."""
    junctions = [
        {
            "id": j.id,
            "at": _point(j.at),
            "seams": list(j.seams),
            "gaps_mm": [_number(g) for g in j.gaps_mm],
            "mismatch_mm": _number(j.mismatch_mm),
            "mismatch_sigma_mm": _number(j.mismatch_sigma_mm),
        }
        for j in result.junctions
    ]
    findings = [finding_document(f) for f in result.findings]
    return {
        "format": RESULT_FORMAT,
        "units": "mm; points [x, y, z] in the cloud's frame; colour differences in CIE76 ΔE",
        "rules": {
            "panels": "numbered by centroid: x (centroids within 10 mm count as one column), "
            "then y, then z",
            "seam panels": "[a, b]: b lies on the + side of the cloud axis (x, y or z) that "
            "the seam's across direction is closest to",
            "step": "b's top over a's, along the mean top normal (towards the sensor)",
        },
        "points": result.point_count,
        "point_spacing_mm": _number(result.spacing_mm),
        "cell_mm": _number(result.cell_mm),
        "panels": [panel_document(p) for p in result.panels],
        "panel_area_m2": _number(result.panel_area_m2, 5),
        "seams": [seam_document(s) for s in result.seams],
        "junctions": junctions,
        "defects": [
            d for d, f in zip(findings, result.findings, strict=True) if f.out_of_tolerance
        ],
        "uncertain": [d for d, f in zip(findings, result.findings, strict=True) if f.uncertain],
        "unmeasured_seams": [
            {"seam": s.id, "panels": list(s.panels), "why": s.unmeasured}
            for s in result.seams
            if s.unmeasured is not None
        ],
        "findings": findings,
        "config": config_document(config),
        "seconds": {k: _number(v, 3) for k, v in result.seconds.items()},
    }


def profile_png(result: MeasureResult, config: MeasureConfig, path: Path) -> None:
    """Gap and step along every seam, with the tolerance limits."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = config.tolerances
    fig, (gap_ax, step_ax) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    unmeasured_label = "unmeasured section"
    for seam in result.seams:
        along = np.linalg.norm(seam.sections_at - seam.start, axis=1)
        label = f"seam {seam.id} (panels {seam.panels[0]}–{seam.panels[1]})"
        line = gap_ax.plot(along, seam.sections_gap_mm, ".-", ms=3, lw=0.8, label=label)[0]
        step_ax.plot(along, seam.sections_step_mm, ".-", ms=3, lw=0.8, color=line.get_color())
        missing = ~seam.measured
        if missing.any():  # drawn on the lower limit, where no gap line runs
            gap_ax.plot(
                along[missing],
                np.full(missing.sum(), t.gap_min_mm),
                "x",
                ms=4,
                color=line.get_color(),
                label=unmeasured_label,
            )
            unmeasured_label = None
    for limit in (t.gap_min_mm, t.gap_max_mm):
        gap_ax.axhline(limit, color="crimson", ls="--", lw=0.8)
    for limit in (-t.step_max_mm, t.step_max_mm):
        step_ax.axhline(limit, color="crimson", ls="--", lw=0.8)
    gap_ax.set_ylabel("gap (mm)")
    step_ax.set_ylabel("step (mm)")
    step_ax.set_xlabel("distance from the seam's start (mm)")
    gap_ax.set_title("Seam profiles (dashed: tolerance)")
    if result.seams:
        # beside the axes, where it covers neither a profile nor a tolerance line
        gap_ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    else:
        why = f"no seams: the cloud holds {counted(len(result.panels), 'panel')}, no two adjacent"
        for ax in (gap_ax, step_ax):
            ax.text(0.5, 0.5, why, transform=ax.transAxes, ha="center", va="center")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
