"""Job handlers ``stitching.calibrate`` and ``stitching.stitch``: artifacts in, artifacts out,
progress between; the work is ``run.calibrate_pairs`` and ``run.stitch_files``, as the
commands'."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contract.context import JobContext, in_user_words, input_error, one_input
from contract.errors import JobInputError
from services.lib.pointcloud.ply import PLY_MEDIA_TYPE
from services.stitching.files import StitchingFileError, handeye_json, load_json, parse_scans
from services.stitching.kinds import HANDEYE, OVERLAP_PLOT, STITCH_REPORT, STITCHED_CLOUD
from services.stitching.run import calibrate_pairs, stitch_files, write_stitched


def calibrate_job(ctx: JobContext) -> dict:
    params = ctx.params
    pairs = one_input(ctx, "pairs", "PAIRS.json")
    ctx.progress(0.05, f"calibrating ({params.method}) from {pairs.name}")
    try:
        result = calibrate_pairs(pairs.path, params)
    except ValueError as exc:
        raise input_error(pairs, exc) from exc
    document = handeye_json(result)
    ctx.add_artifact_json(document, kind=HANDEYE.kind, name=HANDEYE.file_name())
    ctx.progress(1.0, f"residual {result.residual_mm:.4f} mm, {len(result.dropped)} pairs dropped")
    return {
        "method": result.method,
        "residual_mm": result.residual_mm,
        "pairs": len(result.pair_residuals_mm),
        "dropped_pairs": [d.index for d in result.dropped],
        "sigma_translation_mm": result.sigma_translation_mm,
        "sigma_rotation_deg": result.sigma_rotation_deg,
    }


def stitch_job(ctx: JobContext) -> dict:
    files, base_T_flange = _scan_files(ctx)
    handeye = one_input(ctx, "handeye", "HANDEYE.json")
    try:
        stitched = stitch_files(
            files,
            base_T_flange,
            handeye.path,
            ctx.params,
            progress=lambda fraction, message: ctx.progress(0.9 * fraction, message),
        )
    except ValueError as exc:
        raise JobInputError(in_user_words(str(exc), ctx, list(ctx.inputs))) from exc
    ctx.progress(0.9, "storing results")
    cloud, plot = ctx.workdir / STITCHED_CLOUD.file_name(), ctx.workdir / OVERLAP_PLOT.file_name()
    write_stitched(stitched, cloud, plot)
    points = len(stitched.result.cloud.points)
    meta = {"point_count": points, "scans": len(files)}
    ctx.add_artifact_file(
        cloud, kind=STITCHED_CLOUD.kind, name=cloud.name, media_type=PLY_MEDIA_TYPE, meta=meta
    )
    ctx.add_artifact_json(stitched.report, kind=STITCH_REPORT.kind, name=STITCH_REPORT.file_name())
    ctx.add_artifact_file(plot, kind=OVERLAP_PLOT.kind, name=plot.name, media_type="image/png")
    ctx.progress(1.0, stitched.summary()[0])
    return {
        "points": points,
        "scans": len(files),
        "overlap_mean_mm": stitched.report["overall"]["mean_mm"],
        "overlap_p90_mm": stitched.report["overall"]["p90_mm"],
        "calibration_method": stitched.report["calibration"]["method"],
        "icp": ctx.params.icp,
    }


def _scan_files(ctx: JobContext) -> tuple[list[Path], np.ndarray]:
    """The job's SCANS.json: the PLY inputs it names (by artifact name), and their poses."""
    manifest = one_input(ctx, "scans", "SCANS.json")
    try:
        names, base_T_flange = parse_scans(load_json(manifest.path), manifest.name)
    except StitchingFileError as exc:
        raise input_error(manifest, exc) from exc
    scans = {a.name: a for a in ctx.inputs if a.media_type == PLY_MEDIA_TYPE}
    missing = [name for name in names if Path(name).name not in scans]
    if missing:
        raise JobInputError(
            f"{manifest.name} names scans that are not inputs of this job: {missing}; "
            f"PLY inputs: {sorted(scans) or 'none'}"
        )
    return [scans[Path(name).name].path for name in names], base_T_flange
