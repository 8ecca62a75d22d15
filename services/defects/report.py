"""RESULT.json and the gap/step profile plot of a measurement."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.defects.config import MeasureConfig, config_document
from services.defects.measure import Finding, MeasureResult

RESULT_FORMAT = "vista.defects/1"


def _point(p: np.ndarray) -> list[float]:
    return [round(float(v), 4) for v in p]


def _number(value: float, digits: int = 4) -> float | None:
    return round(float(value), digits) if np.isfinite(value) else None


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
        **f.source,
        "measurements": {
            k: (_number(v) if isinstance(v, float) else v) for k, v in f.measurements.items()
        },
    }


def result_document(result: MeasureResult, config: MeasureConfig) -> dict:
    """RESULT.json: seams, junctions, defects (out of tolerance) and every finding."""
    seams = [
        {
            "id": s.id,
            "panels": list(s.panels),
            "start": _point(s.start),
            "end": _point(s.end),
            "length_mm": _number(s.length_mm, 3),
            "gap_mm": {k: _number(v) for k, v in vars(s.gap_mm).items()},
            "step_mm": {k: _number(v) for k, v in vars(s.step_mm).items()},
            "parallelism_mm": _number(s.parallelism_mm),
            "gap_at_ends_mm": [_number(g) for g in s.gap_at_ends_mm],
            "gap_sigma_mm": _number(s.gap_sigma_mm),
            "edge_radius_mm": [_number(r, 3) for r in s.edge_radius_mm],
            "edge_fit_rms_mm": _number(s.edge_fit_rms_mm),
            "normal": _point(s.normal),
            "sections": [
                {"at": _point(at), "gap_mm": _number(g), "step_mm": _number(st)}
                for at, g, st in zip(
                    s.sections_at, s.sections_gap_mm, s.sections_step_mm, strict=True
                )
            ],
        }
        for s in result.seams
    ]
    junctions = [
        {
            "id": j.id,
            "at": _point(j.at),
            "seams": list(j.seams),
            "gaps_mm": [_number(g) for g in j.gaps_mm],
            "mismatch_mm": _number(j.mismatch_mm),
        }
        for j in result.junctions
    ]
    findings = [finding_document(f) for f in result.findings]
    return {
        "format": RESULT_FORMAT,
        "units": "mm; points [x, y, z] in the cloud's frame; colour differences in CIE76 ΔE",
        "points": result.point_count,
        "point_spacing_mm": _number(result.spacing_mm),
        "cell_mm": _number(result.cell_mm),
        "panels": [
            {"id": i, "area_mm2": _number(a, 1)} for i, a in enumerate(result.panel_areas_mm2)
        ],
        "panel_area_m2": _number(result.panel_area_m2, 5),
        "seams": seams,
        "junctions": junctions,
        "defects": [
            d for d, f in zip(findings, result.findings, strict=True) if f.out_of_tolerance
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
    for seam in result.seams:
        along = np.linalg.norm(seam.sections_at - seam.start, axis=1)
        label = f"seam {seam.id} (panels {seam.panels[0]}–{seam.panels[1]})"
        gap_ax.plot(along, seam.sections_gap_mm, ".-", ms=3, lw=0.8, label=label)
        step_ax.plot(along, seam.sections_step_mm, ".-", ms=3, lw=0.8)
    for limit in (t.gap_min_mm, t.gap_max_mm):
        gap_ax.axhline(limit, color="crimson", ls="--", lw=0.8)
    for limit in (-t.step_max_mm, t.step_max_mm):
        step_ax.axhline(limit, color="crimson", ls="--", lw=0.8)
    gap_ax.set_ylabel("gap (mm)")
    step_ax.set_ylabel("step (mm)")
    step_ax.set_xlabel("distance from the seam's start (mm)")
    gap_ax.set_title("Seam profiles (dashed: tolerance)")
    if result.seams:
        gap_ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
