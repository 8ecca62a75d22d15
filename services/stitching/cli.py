"""``vista calibrate`` and ``vista simulate stitching``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from services.pointcloud.transforms import pose_error, to_json


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def calibrate(
    pairs: Path = typer.Argument(
        ..., help='PAIRS.json: {"pairs": [{base_T_flange, sensor_T_target}, …]}'
    ),
    out: Path = typer.Option(..., "-o", "--out", help="Where to write HANDEYE.json."),
    method: str = typer.Option(
        "vista", help="vista | thesis | tsai | park | horaud | andreff | daniilidis"
    ),
    robot_sigma_mm: float = typer.Option(0.05, help="Robot repeatability, 1σ per axis (mm)."),
    robot_sigma_deg: float = typer.Option(0.005, help="Robot orientation noise, 1σ per axis."),
    sensor_sigma_mm: float = typer.Option(0.02, help="Plate-pose noise of the sensor (mm)."),
    sensor_sigma_deg: float = typer.Option(0.02, help="Plate-pose noise of the sensor (deg)."),
) -> None:
    """Robot–sensor calibration: flange_T_sensor (and the plate's base_T_target) from pairs of
    reported robot pose and measured plate pose. The noise options weigh the vista method."""
    from services.stitching.calibration import (
        METHODS,
        CalibrationError,
        NoiseModel,
    )
    from services.stitching.calibration import (
        calibrate as run_calibration,
    )
    from services.stitching.files import StitchingFileError, read_pairs, write_handeye

    if method not in METHODS:
        _fail(f"--method must be one of {', '.join(METHODS)}; got {method!r}")
    try:
        base_T_flange, sensor_T_target = read_pairs(pairs)
        noise = NoiseModel(robot_sigma_mm, robot_sigma_deg, sensor_sigma_mm, sensor_sigma_deg)
        result = run_calibration(base_T_flange, sensor_T_target, method=method, noise=noise)
    except (StitchingFileError, CalibrationError) as exc:
        _fail(str(exc))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_handeye(out, result)
    typer.echo(
        f"{method}: residual {result.residual_mm:.4f} mm over {len(result.used_pairs)} of "
        f"{len(base_T_flange)} pairs in {result.seconds * 1000:.1f} ms"
    )
    if result.sigma_translation_mm is not None:
        typer.echo(
            f"uncertainty (1σ): {result.sigma_translation_mm:.4f} mm, "
            f"{result.sigma_rotation_deg:.4f}°"
        )
    for dropped in result.dropped:
        typer.echo(
            f"dropped pair {dropped.index}: residual {dropped.residual_mm:.3f} mm, "
            f"χ² {dropped.chi2:.0f} (a pair that fits its noise has about 6)"
        )
    typer.echo(f"wrote {out}")


def simulate_stitching(
    out_dir: Path = typer.Argument(..., help="Folder to write the example into."),
    poses: int = typer.Option(15, min=3, help="Calibration poses."),
    corrupt: int = typer.Option(0, min=0, help="Calibration pairs with a mis-detected plate."),
    seed: int = typer.Option(0, help="Random seed."),
) -> None:
    """Write a simulated calibration session (pairs.json) with its ground truth (truth.json)."""
    from services.stitching.calibration_sim import simulate_calibration
    from services.stitching.files import write_pairs

    if corrupt >= poses:
        _fail(f"--corrupt ({corrupt}) must be less than --poses ({poses})")
    session = simulate_calibration(poses=poses, corrupt=corrupt, rng=np.random.default_rng(seed))
    out_dir.mkdir(parents=True, exist_ok=True)
    write_pairs(out_dir / "pairs.json", session.base_T_flange, session.sensor_T_target)
    truth = {
        "flange_T_sensor": to_json(session.true_flange_T_sensor),
        "base_T_target": to_json(session.true_base_T_target),
        "true_base_T_flange": [to_json(t) for t in session.true_base_T_flange],
        "corrupted_pairs": list(session.corrupted),
        "seed": seed,
    }
    (out_dir / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    typer.echo(f"wrote {out_dir / 'pairs.json'} ({poses} pairs) and {out_dir / 'truth.json'}")


def compare_handeye(
    handeye: Path = typer.Argument(..., help="HANDEYE.json written by `vista calibrate`."),
    truth: Path = typer.Argument(..., help="truth.json written by `vista simulate stitching`."),
) -> None:
    """How far a calibration is from the simulated truth (translation mm, rotation deg)."""
    from services.stitching.files import StitchingFileError, load_json, read_handeye

    try:
        flange_T_sensor, _ = read_handeye(handeye)
        true_flange_T_sensor = np.asarray(load_json(truth)["flange_T_sensor"], dtype=float)
    except (StitchingFileError, KeyError) as exc:
        _fail(str(exc))
    translation_mm, rotation_deg = pose_error(flange_T_sensor, true_flange_T_sensor)
    typer.echo(f"flange_T_sensor error: {translation_mm:.4f} mm, {rotation_deg:.4f}°")


def register(app: typer.Typer, simulate_app: typer.Typer) -> None:
    app.command("calibrate")(calibrate)
    app.command("calibration-error")(compare_handeye)
    simulate_app.command("stitching")(simulate_stitching)
