"""``vista depth …``: the monocular depth service's commands."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from contract.cli import fail

# Heavy imports (numpy, OpenCV, torch) stay inside the commands.

depth_app = typer.Typer(
    help="Monocular depth: simulate driving scenes with dense depth, train a teacher, distil a "
    "small student, predict and evaluate in KITTI's conventions.",
    no_args_is_help=True,
)


@depth_app.command("simulate")
def simulate(
    out_dir: Path = typer.Argument(..., help="The drive folder to write."),
    frames: int = typer.Option(5, min=1, max=100_000, help="Frames of the drive (10 Hz)."),
    stereo: bool = typer.Option(
        False, "--stereo", help="Also render the right camera (image_03/)."
    ),
    seed: int = typer.Option(0, min=0, help="Random seed (street, traffic, light, camera path)."),
    width: int = typer.Option(1242, min=32, max=8192, help="Image width (KITTI: 1242)."),
    height: int = typer.Option(375, min=16, max=8192, help="Image height (KITTI: 375)."),
) -> None:
    """Render a drive down a random street (lanes, kerbs, façades, trees, poles, parked and
    moving cars, trucks, bridges, sky; random sun, exposure and noise) through KITTI's camera
    (f = 721.5 px at 1242 × 375, scaled with the size; stereo baseline 0.533 m) in KITTI's
    layout: image_02/*.png, image_03/*.png (--stereo), depth/*.png (uint16 metres × 256,
    0 = sky), calib.json (K at the image size, baseline_m) and poses.txt (KITTI odometry
    format)."""
    from services.depth.camera import kitti_camera
    from services.depth.simulate import simulate_drive

    camera = kitti_camera().resized(width, height)
    with typer.progressbar(length=frames, label="rendering") as bar:
        simulate_drive(
            out_dir,
            frames=frames,
            stereo=stereo,
            seed=seed,
            camera=camera,
            progress=lambda _: bar.update(1),
        )
    typer.echo(f"wrote {frames} frame{'s' * (frames > 1)} ({width} × {height}) to {out_dir}")


@depth_app.command("eval")
def evaluate(
    pred_dir: Path = typer.Argument(..., help="Predicted depth PNGs (KITTI convention)."),
    gt_dir: Path = typer.Argument(..., help="Ground-truth depth PNGs, matched by file name."),
    median_scaling: bool = typer.Option(
        False,
        "--median-scaling",
        help="Scale each prediction by the ratio of medians (monocular models).",
    ),
    crop: str = typer.Option("garg", help="garg (monodepth2's Eigen-split crop), eigen or none."),
    max_depth: float = typer.Option(80.0, min=0.01, max=655.0, help="Cap, metres (KITTI: 80)."),
    out: Path = typer.Option(..., "-o", "--out", help="EVAL.json to write."),
) -> None:
    """Monodepth2's evaluation: per image the seven metrics (abs_rel, sq_rel, rmse,
    rmse_log, δ<1.25, δ<1.25², δ<1.25³) on ground-truth pixels within the crop and
    1e-3 m–--max-depth, the prediction resized to the ground truth and clipped; the
    metrics averaged over images."""
    from services.depth.metrics import CROPS, evaluate_folders

    if crop not in CROPS:
        fail(f"--crop {crop!r}: known crops are {', '.join(CROPS)}")
    try:
        result = evaluate_folders(
            pred_dir, gt_dir, crop=crop, median_scaling=median_scaling, max_depth_m=max_depth
        )
    except ValueError as exc:
        fail(str(exc))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result.to_json(), indent=1))
    m = result.metrics
    typer.echo(
        f"{len(result.images)} images: abs_rel {m.abs_rel:.3f}, sq_rel {m.sq_rel:.3f}, rmse "
        f"{m.rmse:.3f} m, rmse_log {m.rmse_log:.3f}, δ1 {m.delta1:.3f}, δ2 {m.delta2:.3f}, "
        f"δ3 {m.delta3:.3f}"
    )
    if result.missing:
        typer.echo(
            f"warning: {len(result.missing)} ground-truth images had no prediction: {result.missing[:5]}"
        )
    typer.echo(f"wrote {out}")


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    app.add_typer(depth_app, name="depth")
