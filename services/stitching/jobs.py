"""Job handlers ``stitching.calibrate`` and ``stitching.stitch``: artifacts in, artifacts out, progress between."""

from __future__ import annotations

from pathlib import Path

from contract.context import JobContext, input_error, one_input
from contract.errors import JobInputError
from services.lib.pointcloud.ply import PLY_MEDIA_TYPE, PlyError, read_ply, write_ply
from services.stitching.calibration import CalibrationError, NoiseModel, calibrate
from services.stitching.files import (
    StitchingFileError,
    handeye_json,
    load_json,
    parse_scans,
    read_handeye,
    read_pairs,
)
from services.stitching.kinds import HANDEYE, OVERLAP_PLOT, STITCH_REPORT, STITCHED_CLOUD
from services.stitching.quality import histogram_png
from services.stitching.report import stitch_config, stitch_report
from services.stitching.stitch import stitch


def calibrate_job(ctx: JobContext) -> dict:
    params = ctx.params
    pairs = one_input(ctx, "pairs", "PAIRS.json")
    ctx.progress(0.05, f"reading {pairs.name}")
    try:
        base_T_flange, sensor_T_target = read_pairs(pairs.path)
    except StitchingFileError as exc:
        raise input_error(pairs, exc) from exc
    ctx.progress(0.1, f"calibrating ({params.method}) from {len(base_T_flange)} pairs")
    try:
        noise = NoiseModel.of(params)
        result = calibrate(base_T_flange, sensor_T_target, method=params.method, noise=noise)
    except CalibrationError as exc:
        raise input_error(pairs, exc) from exc
    document = handeye_json(result)
    ctx.add_artifact_json(document, kind=HANDEYE.kind, name=HANDEYE.file_name())
    ctx.progress(1.0, f"residual {result.residual_mm:.4f} mm, {len(result.dropped)} pairs dropped")
    return {
        "method": result.method,
        "residual_mm": result.residual_mm,
        "pairs": len(base_T_flange),
        "dropped_pairs": [d.index for d in result.dropped],
        "sigma_translation_mm": result.sigma_translation_mm,
        "sigma_rotation_deg": result.sigma_rotation_deg,
    }


def stitch_job(ctx: JobContext) -> dict:
    params = ctx.params
    manifest = one_input(ctx, "scans", "SCANS.json")
    handeye = one_input(ctx, "handeye", "HANDEYE.json")
    try:
        names, base_T_flange = parse_scans(load_json(manifest.path), manifest.name)
    except StitchingFileError as exc:
        raise input_error(manifest, exc) from exc
    try:
        flange_T_sensor, calibration = read_handeye(handeye.path)
    except StitchingFileError as exc:
        raise input_error(handeye, exc) from exc
    scans = {a.name: a for a in ctx.inputs if a.media_type == PLY_MEDIA_TYPE}
    missing = [name for name in names if Path(name).name not in scans]
    if missing:
        raise JobInputError(
            f"{manifest.name} names scans that are not inputs of this job: {missing}; "
            f"PLY inputs: {sorted(scans) or 'none'}"
        )
    try:
        config = stitch_config(params, calibration)
    except ValueError as exc:
        raise JobInputError(str(exc)) from exc
    clouds = []
    for i, name in enumerate(names):
        artifact = scans[Path(name).name]
        ctx.progress(0.3 * i / len(names), f"reading {artifact.name}")
        try:
            clouds.append(read_ply(artifact.path))
        except PlyError as exc:
            raise input_error(artifact, exc) from exc

    result = stitch(
        clouds,
        base_T_flange,
        flange_T_sensor,
        config=config,
        progress=lambda fraction, message: ctx.progress(0.3 + 0.5 * fraction, message),
    )
    ctx.progress(0.8, "measuring the overlap quality")
    quality, document = stitch_report(result, config=config, calibration=calibration)
    cloud_path = ctx.workdir / STITCHED_CLOUD.file_name()
    write_ply(cloud_path, result.cloud, comments=("vista stitched, base frame, mm",))
    plot_path = ctx.workdir / OVERLAP_PLOT.file_name()
    histogram_png(quality, plot_path)
    ctx.progress(0.95, "storing results")
    ctx.add_artifact_file(
        cloud_path,
        kind=STITCHED_CLOUD.kind,
        name=cloud_path.name,
        media_type=PLY_MEDIA_TYPE,
        meta={"point_count": len(result.cloud.points), "scans": len(clouds)},
    )
    ctx.add_artifact_json(document, kind=STITCH_REPORT.kind, name=STITCH_REPORT.file_name())
    ctx.add_artifact_file(
        plot_path, kind=OVERLAP_PLOT.kind, name=plot_path.name, media_type="image/png"
    )
    o = quality.overall
    ctx.progress(1.0, f"{len(result.cloud.points)} points; overlap mean {o.mean_mm:.4f} mm")
    return {
        "points": len(result.cloud.points),
        "scans": len(clouds),
        "overlap_mean_mm": document["overall"]["mean_mm"],
        "overlap_p90_mm": document["overall"]["p90_mm"],
        "calibration_method": calibration.get("method"),
        "icp": params.icp,
    }
