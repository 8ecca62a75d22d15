"""``vista stitching calibrate|calibration-error|stitch|simulate|bench``; the old spellings
(``vista calibrate``, ``vista simulate stitching`` …) kept as hidden aliases for a release."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from contract.cli import alias, fail, params_options, progress_bar
from services.stitching.kinds import CalibrateParams, StitchParams

# Heavy imports (numpy, scipy, open3d) stay inside the commands: every `vista` invocation
# and every API process imports this module.


@params_options(CalibrateParams)
def calibrate(
    pairs: Path = typer.Argument(
        ..., help='PAIRS.json: {"pairs": [{base_T_flange, sensor_T_target}, …]}'
    ),
    out: Path = typer.Option(..., "-o", "--out", help="Where to write HANDEYE.json."),
    *,
    params: CalibrateParams,
) -> None:
    """Robot–sensor calibration: flange_T_sensor (and the plate's base_T_target) from pairs of
    reported robot pose and measured plate pose. The noise options weigh the vista method;
    HANDEYE.json keeps them (a bounded ICP stitch moves scans within the robot's)."""
    from services.stitching.files import write_handeye
    from services.stitching.run import calibrate_pairs

    try:
        result = calibrate_pairs(pairs, params)
    except ValueError as exc:
        fail(str(exc))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_handeye(out, result)
    typer.echo(
        f"{result.method}: residual {result.residual_mm:.4f} mm over {len(result.used_pairs)} "
        f"of {len(result.pair_residuals_mm)} pairs in {result.seconds * 1000:.1f} ms"
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
    component: str = typer.Option(
        "angle", help="angle (carbon angle profile) | flat | curved | strip (585 × 170 mm)"
    ),
    poses: int = typer.Option(15, min=3, help="Calibration poses."),
    corrupt: int = typer.Option(0, min=0, help="Calibration pairs with a mis-detected plate."),
    full_scale: bool = typer.Option(
        False, help="Gocator 3210 grids (1288 × 1936, ~2.5 M points a scan) instead of 250 × 385."
    ),
    seed: int = typer.Option(0, help="Random seed."),
) -> None:
    """Write a complete stitching example with its ground truth: a calibration session
    (pairs.json), scans of a component along a workplan (scan_NNN.ply, scans.json), and
    truth.json (true mount, true robot poses, the part's pose and bounding box)."""
    from services.lib.pointcloud import scan_sim
    from services.stitching.example import write_example

    if corrupt >= poses:
        fail(f"--corrupt ({corrupt}) must be less than --poses ({poses})")
    if component not in scan_sim.COMPONENTS:
        fail(f"--component must be one of {', '.join(scan_sim.COMPONENTS)}; got {component!r}")
    grid = scan_sim.GOCATOR_GRID if full_scale else (250, 385)
    example = write_example(
        out_dir, component=component, poses=poses, corrupt=corrupt, grid=grid, seed=seed
    )
    typer.echo(
        f"wrote {out_dir}: pairs.json ({poses} pairs), {example.scans} scans of the "
        f"{example.component_name} ({grid[0]} × {grid[1]}), scans.json, truth.json"
    )


@params_options(StitchParams)
def stitch(
    scans: Path = typer.Argument(..., help='SCANS.json: {"scans": [{file, base_T_flange}, …]}'),
    handeye: Path = typer.Option(..., help="HANDEYE.json from `vista stitching calibrate`."),
    out: Path = typer.Option(..., "-o", "--out", help="Where to write the stitched PLY."),
    report: Path = typer.Option(
        ..., help="Where to write REPORT.json (a .png plot goes beside it)."
    ),
    truth: Path = typer.Option(
        None, help="truth.json of `vista stitching simulate`: adds the true errors."
    ),
    *,
    params: StitchParams,
) -> None:
    """Stitch scans into the robot base frame with the calibration, clean them (LoOP,
    closest-vertex merge, final filter) and report the overlap quality (Fig. 6.2)."""
    from services.stitching.files import read_scans
    from services.stitching.run import stitch_files, write_stitched

    try:
        files, base_T_flange = read_scans(scans)
        with progress_bar("stitching") as step:
            stitched = stitch_files(
                files, base_T_flange, handeye, params, truth=truth, progress=step
            )
    except ValueError as exc:
        fail(str(exc))
    out.parent.mkdir(parents=True, exist_ok=True)
    report.parent.mkdir(parents=True, exist_ok=True)
    write_stitched(stitched, out, report.with_suffix(".png"))
    report.write_text(json.dumps(stitched.report, indent=1) + "\n")
    for line in stitched.summary():
        typer.echo(line)
    typer.echo(f"wrote {out}, {report} and {report.with_suffix('.png')}")


def compare_handeye(
    handeye: Path = typer.Argument(
        ..., help="HANDEYE.json written by `vista stitching calibrate`."
    ),
    truth: Path = typer.Argument(..., help="truth.json written by `vista stitching simulate`."),
) -> None:
    """How far a calibration is from the simulated truth (translation mm, rotation deg)."""
    import numpy as np

    from services.lib.pointcloud.transforms import pose_error
    from services.stitching.files import StitchingFileError, load_json, read_handeye

    try:
        flange_T_sensor, _ = read_handeye(handeye)
        true_flange_T_sensor = np.asarray(load_json(truth)["flange_T_sensor"], dtype=float)
    except (StitchingFileError, KeyError) as exc:
        fail(str(exc))
    translation_mm, rotation_deg = pose_error(flange_T_sensor, true_flange_T_sensor)
    typer.echo(f"flange_T_sensor error: {translation_mm:.4f} mm, {rotation_deg:.4f}°")


def bench_stitching(
    out: Path = typer.Option(Path("bench-results/stitching.json"), help="Where to write the JSON."),
    sessions: int = typer.Option(100, min=3, help="Simulated calibration sessions per case."),
    thesis_sessions: int = typer.Option(
        30, min=1, help="Of those, how many also run basin hopping (seconds each)."
    ),
    full_scale: bool = typer.Option(
        True, help="Run the full-scale part (10 × 2.5 M points, vista vs Open3D)."
    ),
    seed: int = typer.Option(0, help="Random seed."),
) -> None:
    """Stitching at full scale against Open3D (time, peak memory, accuracy) and calibration
    accuracy against the thesis's method and OpenCV; prints tables, writes JSON."""
    from services.stitching.bench import run_stitching_bench

    run_stitching_bench(
        out,
        sessions=sessions,
        thesis_sessions=thesis_sessions,
        full_scale=full_scale,
        seed=seed,
    )


def register(app: typer.Typer, simulate_app: typer.Typer, bench_app: typer.Typer) -> None:
    stitching_app = typer.Typer(
        help="Hand-eye calibration and scan stitching into the robot's base frame.",
        no_args_is_help=True,
    )
    verbs = {"calibrate": calibrate, "calibration-error": compare_handeye, "stitch": stitch}
    for verb, command in verbs.items():
        stitching_app.command(verb)(command)
        alias(app, verb, command, f"stitching {verb}")
    stitching_app.command("simulate")(simulate_stitching)
    stitching_app.command("bench")(bench_stitching)
    app.add_typer(stitching_app, name="stitching")
    alias(simulate_app, "stitching", simulate_stitching, "stitching simulate")
    alias(bench_app, "stitching", bench_stitching, "stitching bench")
