"""``vista odometry …``: the floor-camera odometry service's commands."""

from __future__ import annotations

from pathlib import Path

import typer

from contract.cli import fail

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
        done = simulate_sequence(
            out_dir,
            floor=floor,
            path=path,
            seconds=seconds,
            fps=fps,
            seed=seed,
            effects=effects,
            progress=typer.echo,
        )
    except ValueError as exc:
        fail(str(exc))
    typer.echo(
        f"wrote {out_dir}: {len(done.truth)} frames in frames/ "
        f"({done.camera.width} × {done.camera.height}, {done.camera.mm_per_px:.4f} mm/px), "
        f"camera.json, truth.tum ({done.distance_mm / 1000:.3f} m in {done.truth.t_s[-1]:.2f} s)"
    )


def register(app: typer.Typer) -> None:
    app.add_typer(odometry_app, name="odometry")
