"""Job handler ``defects.measure``: a stitched cloud and the inspection's tolerances in; RESULT.json,
the profile plot and the defects out."""

from __future__ import annotations

import numpy as np

from contract.context import JobContext, NewDefect, input_error, one_input
from contract.errors import JobInputError
from contract.tolerances import limits_of
from services.defects.config import measure_config
from services.defects.kinds import PROFILES, RESULT
from services.defects.measure import Finding, MeasureError, MeasureResult, SeamResult, measure
from services.defects.report import finding_document, profile_png, result_document
from services.lib.pointcloud.ply import PlyError, read_ply
from services.lib.wording import counted


def _new_defect(finding: Finding, severity: str | None = None) -> NewDefect:
    document = finding_document(finding)
    in_mm = finding.unit == "mm"
    return NewDefect(
        type=finding.type,
        location_mm=tuple(document["location"]),
        normal=tuple(document["normal"]),
        value_mm=document["value"] if in_mm else None,
        tolerance_mm=document["tolerance"] if in_mm else None,
        extent_mm=document["extent_mm"],
        severity=severity or finding.severity,
        confidence=document["confidence"],
        measurements={
            "value": document["value"],
            "unit": finding.unit,
            "tolerance": document["tolerance"],
            **finding.source,
            **document["measurements"],
        },
    )


def _in_tolerance_seams(result: MeasureResult) -> list[NewDefect]:
    """One `info` row per seam none of whose measurements is out of tolerance or
    uncertain."""
    flagged = {f.source["seam"] for f in result.defects + result.uncertain if "seam" in f.source}
    rows = []
    for finding in result.findings:
        seam = finding.source.get("seam")
        if finding.type == "gap" and seam not in flagged:
            rows.append(_new_defect(finding, severity="info"))
    return rows


def measure_job(ctx: JobContext) -> dict:
    params = ctx.params
    cloud = one_input(ctx, "cloud", "the stitched point cloud")
    config = measure_config(limits_of(ctx.tolerances), params)
    ctx.progress(0.02, f"reading {cloud.name}")
    try:
        points = read_ply(cloud.path)
    except PlyError as exc:
        raise input_error(cloud, exc) from exc
    try:
        result = measure(
            points,
            config,
            threads=ctx.threads,
            progress=lambda fraction, message: ctx.progress(0.1 + 0.8 * fraction, message),
        )
    except MeasureError as exc:
        raise JobInputError(f"{cloud.label}: {exc}") from exc
    ctx.progress(0.92, "storing results")
    ctx.add_artifact_json(
        result_document(result, config), kind=RESULT.kind, name=RESULT.file_name()
    )
    plot = ctx.workdir / PROFILES.file_name()
    profile_png(result, config, plot)
    ctx.add_artifact_file(plot, kind=PROFILES.kind, name=plot.name, media_type="image/png")
    defects = [_new_defect(f) for f in result.defects + result.uncertain]
    if params.keep_in_tolerance:
        defects += _in_tolerance_seams(result)
    for defect in defects:
        ctx.add_defect(defect)
    by_type: dict[str, int] = {}
    for finding in result.defects:
        by_type[finding.type] = by_type.get(finding.type, 0) + 1
    unmeasured = [s for s in result.seams if s.unmeasured is not None]
    for seam in unmeasured:  # each in the job's log, with why
        ctx.progress(0.97, f"{_seam_name(seam)} unmeasured: {seam.unmeasured}")
    warning = _warning(unmeasured, len(result.seams), len(result.panels))
    ctx.progress(
        1.0,
        f"{counted(len(result.defects), 'defect')} out of tolerance, "
        f"{len(result.uncertain)} uncertain, in {counted(len(result.seams), 'seam')}"
        + (f"; {len(unmeasured)} of them unmeasured" if unmeasured else ""),
    )
    return {
        **({"warning": warning} if warning else {}),
        "panels": len(result.panels),
        "panel_area_m2": round(result.panel_area_m2, 5),
        "seams": len(result.seams),
        "unmeasured_seams": sum(s.unmeasured is not None for s in result.seams),
        "unmeasured_sections": sum(int((~s.measured).sum()) for s in result.seams),
        "junctions": len(result.junctions),
        "defects": len(result.defects),
        "uncertain": len(result.uncertain),
        "defects_by_type": by_type,
        "seconds": round(sum(result.seconds.values()), 3),
        "cloud_bounds_mm": _bounds_mm(points.points),
    }


def _bounds_mm(points: np.ndarray) -> list[list[float]]:
    """The cloud's axis-aligned box, [min, max] in mm: the area this measurement covers
    (an earlier finding inside it that this one did not find again is no longer current)."""
    finite = points[np.isfinite(points).all(axis=1)]
    return [np.round(finite.min(axis=0), 2).tolist(), np.round(finite.max(axis=0), 2).tolist()]


def _seam_name(seam: SeamResult) -> str:
    return f"seam {seam.id} (P{seam.panels[0]}–P{seam.panels[1]})"


def _warning(unmeasured: list[SeamResult], seams: int, panels: int) -> str | None:
    """What a person must know before signing the measurement off: that it found no seam
    at all, or the seams whose gaps it could not judge, and why (None: every seam
    measured)."""
    if seams == 0:
        return (
            f"no seam found ({counted(panels, 'panel')} told apart): no gap, step, "
            "parallelism or mismatch is judged — if the part has seams, its panels may have "
            "merged on a scan too coarse to show the gaps between them"
        )
    if not unmeasured:
        return None
    head = (
        f"none of the {counted(seams, 'seam')} measured"
        if len(unmeasured) == seams
        else f"{len(unmeasured)} of {counted(seams, 'seam')} unmeasured"
    )
    reasons = "; ".join(f"{_seam_name(s)}: {s.unmeasured}" for s in unmeasured)
    return f"{head}, so their gap, parallelism and mismatch are not judged — {reasons}"
