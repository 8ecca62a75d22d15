"""Job handler ``defects.measure``: a stitched cloud and the inspection's tolerances in; RESULT.json,
the profile plot and the defects out."""

from __future__ import annotations

import numpy as np

from contract.context import (
    JobContext,
    JobInputError,
    NewDefect,
    in_user_words,
    input_error,
    one_input,
)
from contract.findings import DeviationMeasurements, stored
from services.defects.compare import CompareError, compare_cloud
from services.defects.kinds import COMPARISON, DEVIATION_CLOUD, HISTOGRAM, PROFILES, RESULT
from services.defects.measure import Finding, MeasureError, MeasureResult, SeamResult
from services.defects.report import finding_document
from services.defects.run import Measured, measure_cloud
from services.lib.pointcloud.ply import PLY_MEDIA_TYPE
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
    cloud = one_input(ctx, "cloud", "the stitched point cloud")
    ctx.progress(0.02, f"reading {cloud.name}")
    try:
        measured = measure_cloud(
            cloud.path,
            ctx.tolerances,
            ctx.params,
            threads=ctx.threads,
            progress=lambda fraction, message: ctx.progress(0.1 + 0.8 * fraction, message),
        )
    except MeasureError as exc:
        raise input_error(cloud, exc) from exc
    ctx.progress(0.92, "storing results")
    ctx.add_artifact_json(measured.document, kind=RESULT.kind, name=RESULT.file_name())
    plot = ctx.workdir / PROFILES.file_name()
    measured.draw_profiles(plot)
    ctx.add_artifact_file(plot, kind=PROFILES.kind, name=plot.name, media_type="image/png")
    result = measured.result
    defects = [_new_defect(f) for f in result.defects + result.uncertain]
    if ctx.params.keep_in_tolerance:
        defects += _in_tolerance_seams(result)
    for defect in defects:
        ctx.add_defect(defect)
    unmeasured = [s for s in result.seams if s.unmeasured is not None]
    for seam in unmeasured:  # each in the job's log, with why
        ctx.progress(0.97, f"{_seam_name(seam)} unmeasured: {seam.unmeasured}")
    ctx.progress(
        1.0,
        f"{counted(len(result.defects), 'defect')} out of tolerance, "
        f"{len(result.uncertain)} uncertain, in {counted(len(result.seams), 'seam')}"
        + (f"; {len(unmeasured)} of them unmeasured" if unmeasured else ""),
    )
    return _summary(measured, unmeasured)


def _summary(measured: Measured, unmeasured: list[SeamResult]) -> dict:
    """The job's result: what it found, in counts, and the area its cloud covers."""
    result = measured.result
    warning = _warning(unmeasured, len(result.seams), len(result.panels))
    by_type: dict[str, int] = {}
    for finding in result.defects:
        by_type[finding.type] = by_type.get(finding.type, 0) + 1
    return {
        **({"warning": warning} if warning else {}),
        "panels": len(result.panels),
        "panel_area_m2": round(result.panel_area_m2, 5),
        "seams": len(result.seams),
        "unmeasured_seams": len(unmeasured),
        "unmeasured_sections": sum(int((~s.measured).sum()) for s in result.seams),
        "junctions": len(result.junctions),
        "defects": len(result.defects),
        "uncertain": len(result.uncertain),
        "defects_by_type": by_type,
        "seconds": round(sum(result.seconds.values()), 3),
        "cloud_bounds_mm": measured.cloud_bounds_mm,
    }


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


def compare_job(ctx: JobContext) -> dict:
    """``defects.compare``: the cloud against the nominal; the comparison, the deviation
    cloud and histogram stored, each area beyond the profile band a `deviation` finding."""
    cloud = one_input(ctx, "cloud", "the scan")
    nominal = one_input(ctx, "nominal", "the part's nominal model")
    ctx.progress(0.02, f"reading {cloud.name} and {nominal.name}")
    try:
        compared = compare_cloud(
            cloud.path,
            nominal.path,
            ctx.tolerances,
            ctx.params,
            threads=ctx.threads,
            progress=lambda fraction, message: ctx.progress(0.05 + 0.85 * fraction, message),
        )
    except CompareError as exc:
        raise JobInputError(in_user_words(str(exc), ctx, [cloud, nominal])) from exc
    ctx.progress(0.92, "storing results")
    document = compared.document  # the inputs by the names people gave them
    document["cloud"], document["nominal"]["file"] = cloud.name, nominal.name
    ctx.add_artifact_json(document, kind=COMPARISON.kind, name=COMPARISON.file_name())
    for output, write, media_type in (
        (DEVIATION_CLOUD, compared.write_cloud, PLY_MEDIA_TYPE),
        (HISTOGRAM, compared.write_histogram, "image/png"),
    ):
        path = ctx.workdir / output.file_name()
        write(path)
        ctx.add_artifact_file(path, kind=output.kind, name=path.name, media_type=media_type)
    for finding in compared.deviation.findings:
        ctx.add_defect(_deviation_defect(finding.document(), compared.alignment.residual_robust_mm))
    alignment = document["alignment"]
    warnings = [f"alignment: {w}" for w in alignment["warnings"]] + document["warnings"]
    for warning in warnings:
        ctx.progress(0.97, warning)
    found = document["defects"]
    ctx.progress(
        1.0,
        f"{counted(len(found), 'deviation')} beyond the profile band, "
        f"{len(document['uncertain'])} uncertain; aligned ({alignment['method']}) with "
        f"residual {alignment['residual_robust_mm']:.4f} mm",
    )
    aligned = compared.aligned_mm
    return {
        **({"warning": "; ".join(warnings)} if warnings else {}),
        "points": document["points"],
        "alignment": alignment["method"],
        "residual_mm": alignment["residual_robust_mm"],
        "defects": len(found),
        "uncertain": len(document["uncertain"]),
        "regions": len(document["regions"]),
        "seconds": round(sum(document["seconds"].values()), 3),
        "cloud_bounds_mm": [
            np.round(aligned.min(axis=0), 2).tolist(),
            np.round(aligned.max(axis=0), 2).tolist(),
        ],
    }


def _deviation_defect(document: dict, sigma_mm: float) -> NewDefect:
    """A `deviation` finding as the job reports it (its measurements typed by
    ``contract.findings.DeviationMeasurements``)."""
    measurements = DeviationMeasurements(
        value=document["value"],
        unit="mm",
        tolerance=document["tolerance"],
        tolerance_state=document["tolerance_state"],
        sigma_mm=round(sigma_mm, 5),
        region=document["region"],
        mean_mm=document["mean_mm"],
        area_mm2=document["area_mm2"],
        points=document["points"],
        band_mm=tuple(document["band_mm"]),
    )
    return NewDefect(
        type="deviation",
        location_mm=tuple(document["location"]),
        normal=tuple(document["normal"]),
        value_mm=document["value"],
        tolerance_mm=document["tolerance"],
        extent_mm=document["extent_mm"],
        severity=document["severity"],
        confidence=1.0 if document["tolerance_state"] == "out" else 0.5,
        measurements=stored(measurements),
    )
