"""``vista odometry …``: the floor-camera odometry service's commands."""

from __future__ import annotations

import json
import math
from pathlib import Path

import typer

from contract.cli import alias, fail, params_options, progress_bar
from services.odometry.kinds import OdometryParams, TrainParams

# Heavy imports (numpy, OpenCV, torch) stay inside the commands.

odometry_app = typer.Typer(
    help="Floor-camera visual odometry: simulate sequences with ground truth, estimate and "
    "evaluate trajectories.",
    no_args_is_help=True,
)


@odometry_app.command("simulate")
def simulate(
    out_dir: Path = typer.Argument(..., help="Folder to write frames/, camera.json, truth.tum."),
    floor: str = typer.Option(
        "concrete",
        help="concrete, asphalt, tiles, wood, epoxy, worn, low-texture; brick, gravel, grass "
        "(scikit-image's CC0 pictures); or an image file (0.3 mm of floor per pixel).",
    ),
    path: str = typer.Option("loop", help="loop (the thesis-like 28.6 m), lawnmower, random."),
    seconds: float = typer.Option(
        None, min=0.05, max=3600, help="Length of the sequence (default: the path's own)."
    ),
    fps: float = typer.Option(60.0, min=1, max=1000, help="Frames per second."),
    seed: int = typer.Option(0, help="Random seed (floor, path, lighting, noise)."),
    exposure_ms: float = typer.Option(1.0, min=0, max=50, help="Shutter time (motion blur)."),
    gain_swing: float = typer.Option(0.0, min=0, max=0.9, help="Illumination change, ± fraction."),
    shadow: float = typer.Option(0.0, min=0, max=0.95, help="Depth of a moving shadow (0–1)."),
    noise: float = typer.Option(1.0, min=0, max=10, help="Sensor noise (1 = typical)."),
    height_swing_mm: float = typer.Option(
        0.0, min=0, max=20, help="Camera height change, ± mm (scale and focus)."
    ),
) -> None:
    """Simulate a downward floor camera (thesis 6.3: h = 110 mm, f = 3.7 mm, 189.7 mm
    diagonal field, 640 × 480) on a differential-drive robot: the frames as 8-bit grey PNG,
    camera.json and the true poses as truth.tum (metres, frame i in camera 0's frame)."""
    from services.odometry.drive import PATHS
    from services.odometry.floors import PROCEDURAL, SAMPLE_IMAGES
    from services.odometry.render import Effects
    from services.odometry.simulate import simulate_sequence

    if path not in PATHS:
        fail(f"--path {path!r}: known paths are {', '.join(PATHS)}")
    if floor not in PROCEDURAL + SAMPLE_IMAGES and not Path(floor).is_file():
        fail(
            f"--floor {floor!r}: not a floor name ({', '.join(PROCEDURAL + SAMPLE_IMAGES)}) "
            "nor an image file"
        )
    effects = Effects(
        exposure_ms=exposure_ms,
        gain_swing=gain_swing,
        shadow=shadow,
        noise=noise,
        height_swing_mm=height_swing_mm,
    )
    try:
        with progress_bar("rendering frames") as step:
            done = simulate_sequence(
                out_dir,
                floor=floor,
                path=path,
                seconds=seconds,
                fps=fps,
                seed=seed,
                effects=effects,
                frame_progress=lambda done, total: step(done / total),
            )
    except ValueError as exc:
        fail(str(exc))
    typer.echo(
        f"wrote {out_dir}: {len(done.truth)} frames in frames/ "
        f"({done.camera.width} × {done.camera.height}, {done.camera.mm_per_px:.4f} mm/px), "
        f"camera.json, truth.tum ({done.distance_mm / 1000:.3f} m in {done.truth.t_s[-1]:.2f} s)"
    )


def _camera(path: Path):  # noqa: ANN202 - a FloorCamera (imported inside: keep the CLI light)
    from services.odometry.camera import FloorCamera

    try:
        return FloorCamera.from_document(json.loads(path.read_text()))
    except OSError as exc:
        fail(f"{path}: {exc.strerror or exc}")
    except json.JSONDecodeError as exc:
        fail(f"{path}: not JSON ({exc.msg} at line {exc.lineno})")
    except ValueError as exc:
        fail(f"{path}: {exc}")


@odometry_app.command("run")
@params_options(OdometryParams)
def run(
    frames_dir: Path = typer.Argument(..., help="Folder of frames (PNG, in name order)."),
    camera: Path = typer.Option(..., "--camera", help="camera.json of the frames."),
    model: Path = typer.Option(None, help="MODEL.onnx of `vista odometry train` (oenet)."),
    threads: int = typer.Option(
        None, min=1, max=256, help="Threads (default: one per available core)."
    ),
    out: Path = typer.Option(..., "-o", "--out", help="Where to write the trajectory (TUM)."),
    plot: Path = typer.Option(None, help="Also draw the trajectory as a PNG."),
    truth: Path = typer.Option(None, help="truth.tum: drawn beside the estimate in the plot."),
    *,
    params: OdometryParams,
) -> None:
    """Estimate the camera's motion between consecutive frames and chain it into a
    trajectory: TRAJ.tum (metres, frame i at i / fps s, in camera 0's frame) and, beside it,
    TRAJ.json (each pair's motion, confidence and flag; the position's growing 1σ)."""
    from services.lib.process import available_cores, prepare_process
    from services.odometry.report import write_run
    from services.odometry.run import run_odometry
    from services.odometry.tum import read_tum

    prepare_process()
    settings = _camera(camera)
    true = None
    if truth is not None:
        try:
            true = read_tum(truth)
        except (OSError, ValueError) as exc:
            fail(str(exc))
    with progress_bar(f"odometry ({params.method})") as step:
        try:
            result = run_odometry(
                frames_dir,
                settings,
                params,
                model=model,
                threads=threads or available_cores(),
                progress=lambda fraction, message: step(fraction),
            )
        except ValueError as exc:
            fail(str(exc))
    report = out.with_suffix(".json")
    write_run(result, out, report, plot, true)
    final = result.trajectory.pose[-1]
    typer.echo(
        f"{len(result.steps.motion)} pairs at {result.pairs_per_s:.0f} pairs/s, "
        f"{result.flagged} flagged, {result.warned} warned; "
        f"ends at x {final[0] / 1000:.3f} m, y {final[1] / 1000:.3f} m, "
        f"θ {math.degrees(final[2]):.2f}° (1σ {result.sigma_xy_mm[-1]:.1f} mm)"
    )
    typer.echo(f"wrote {out}, {report}" + (f", {plot}" if plot else ""))


@odometry_app.command("train")
@params_options(TrainParams)
def train(
    data_dirs: list[Path] = typer.Argument(
        ..., help="Sequences of `vista odometry simulate` (frames/, camera.json, truth.tum)."
    ),
    out: Path = typer.Option(..., "-o", "--out", help="Where to write MODEL.onnx."),
    checkpoints: Path = typer.Option(
        None, help="Folder for each epoch's checkpoint; a run with the same folder resumes."
    ),
    *,
    params: TrainParams,
) -> None:
    """Train a network on simulated sequences (each pair of consecutive frames is a
    sample) and export it as ONNX with its metadata (architecture, training data, input,
    validation error), checked against torch's output."""
    from contract.training import config_from
    from services.lib.nn.regression import TrainConfig
    from services.lib.process import available_cores
    from services.odometry.oenet import train_oenet, training_summary

    config = config_from(TrainConfig, params, threads=available_cores())
    try:
        metadata = train_oenet(
            data_dirs,
            out,
            config,
            checkpoint_dir=checkpoints,
            progress=lambda fraction, message: typer.echo(message),
        )
    except (OSError, ValueError) as exc:
        fail(str(exc))
    typer.echo(f"wrote {out}: {training_summary(metadata)}")


@odometry_app.command("eval")
def eval_(
    trajectory: Path = typer.Argument(..., help="The estimated trajectory (TUM)."),
    truth: Path = typer.Argument(..., help="The true trajectory (TUM)."),
    out: Path = typer.Option(..., "-o", "--out", help="Where to write EVAL.json."),
) -> None:
    """Per-step RMSE of δx, δy (mm) and δθ (°), the heading's bias per frame, the final
    position error, the ATE (after the best rigid alignment) and the drift in % of the
    distance travelled; with the run's TRAJ.json beside the trajectory, the final error
    against its covariance (NEES, within 2σ)."""
    from services.odometry.evaluate import evaluate
    from services.odometry.report import final_covariance
    from services.odometry.tum import read_tum

    try:
        result = evaluate(
            read_tum(trajectory), read_tum(truth), final_covariance(trajectory.with_suffix(".json"))
        )
    except (OSError, ValueError) as exc:
        fail(str(exc))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result.document(), indent=1) + "\n")
    typer.echo(
        f"{result.poses} poses over {result.distance_m:.3f} m: RMSE δx {result.rmse_dx_mm:.4f} mm, "
        f"δy {result.rmse_dy_mm:.4f} mm, δθ {result.rmse_dtheta_deg:.4f}°; final error "
        f"{result.final_error_m:.4f} m, ATE {result.ate_rmse_m:.4f} m, drift "
        f"{result.drift_percent:.3f} %, heading bias {result.heading_bias_deg:.5f}° a frame"
        + (
            (
                f"; NEES {result.final_nees:.1f} (3 expected)"
                if result.final_nees is not None
                else "; NEES unmeasured (the covariance claims no error in some direction)"
            )
            + f", final error {'within' if result.final_within_2_sigma else 'beyond'} 2σ "
            f"({2 * result.final_sigma_xy_m:.4f} m)"
            if result.final_within_2_sigma is not None
            else ""
        )
    )
    typer.echo(f"wrote {out}")


@odometry_app.command("bench")
def bench_odometry(
    out: Path = typer.Option(Path("bench-results/odometry.json"), help="Where to write the JSON."),
    oenet_model: Path = typer.Option(
        Path("bench-results/odometry/oenet.onnx"),
        help="OE-Net to compare; trained here first (about an hour) when the file is missing.",
    ),
    no_oenet: bool = typer.Option(False, "--no-oenet", help="Leave OE-Net out."),
    work: Path = typer.Option(
        Path("bench-results/odometry/sequences"),
        help="Where the simulated sequences are kept (reused by the next run).",
    ),
    only: list[str] = typer.Option(
        None,
        help="Run only the sweep's cases whose name contains this (repeatable); "
        "'loop' for the circuit alone.",
    ),
) -> None:
    """vista's method, phase correlation and OE-Net on the same simulated frames: the
    thesis-like 28.6 m circuit at 60 fps and a sweep (every floor, one never used in
    training, speeds 0.2–2 m/s, turns, blur, light, height); per-step RMSE, final error,
    drift, flagged pairs, pairs/s on this machine's cores."""
    from services.odometry.bench import LOOP, SWEEP, run_odometry_bench

    cases = SWEEP
    loop = LOOP
    if only:
        cases = tuple(c for c in SWEEP if any(word in c.name for word in only))
        loop = LOOP if "loop" in only else None
        if not cases and loop is None:
            names = ", ".join(c.name for c in SWEEP)
            fail(f"--only {only}: no case's name contains that; cases: loop, {names}")
    run_odometry_bench(
        out, oenet_model=None if no_oenet else oenet_model, work=work, cases=cases, loop=loop
    )


def register(app: typer.Typer, simulate_app: typer.Typer, bench_app: typer.Typer) -> None:
    app.add_typer(odometry_app, name="odometry")
    alias(simulate_app, "odometry", simulate, "odometry simulate")
    alias(bench_app, "odometry", bench_odometry, "odometry bench")
