"""``vista depth …``: the monocular depth service's commands."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from contract.cli import alias, echo_progress, fail, params_options
from services.depth.kinds import BuildSettings, PredictParams, TrainParams

# Heavy imports (numpy, OpenCV, torch) stay inside the commands.

BUILD = BuildSettings()
"""The shipped model's build, whose drives and epochs the bench trains by default."""

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
    partial: bool = typer.Option(
        False,
        "--partial",
        help="Score the names both folders have even when others are on one side only "
        "(listed, with a warning); without it such folders are refused.",
    ),
    out: Path = typer.Option(..., "-o", "--out", help="EVAL.json to write."),
) -> None:
    """Monodepth2's evaluation: per image the seven metrics (abs_rel, sq_rel, rmse,
    rmse_log, δ<1.25, δ<1.25², δ<1.25³) on ground-truth pixels within the crop and
    1e-3 m–--max-depth, the prediction resized to the ground truth and clipped; the
    metrics averaged over images. Predictions and ground truth are matched by file name;
    folders that do not match one to one are refused unless --partial."""
    from services.depth.metrics import CROPS, evaluate_folders

    if crop not in CROPS:
        fail(f"--crop {crop!r}: known crops are {', '.join(CROPS)}")
    try:
        result = evaluate_folders(
            pred_dir, gt_dir, crop=crop, median_scaling=median_scaling, max_depth_m=max_depth
        )
    except ValueError as exc:
        fail(str(exc))
    one_sided = [
        f"{len(names)} {what} ({', '.join(names[:5])}{' …' if len(names) > 5 else ''})"
        for names, what in (
            (result.missing, f"ground-truth PNGs in {gt_dir} have no prediction"),
            (result.unmatched, f"predictions in {pred_dir} have no ground truth"),
        )
        if names
    ]
    if one_sided and not partial:
        fail(
            "; ".join(one_sided)
            + f": the folders do not match (only {len(result.images)} names in both); pass "
            "--partial to score those alone"
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result.to_json(), indent=1))
    m = result.metrics
    typer.echo(
        f"{len(result.images)} images: abs_rel {m.abs_rel:.3f}, sq_rel {m.sq_rel:.3f}, rmse "
        f"{m.rmse:.3f} m, rmse_log {m.rmse_log:.3f}, δ1 {m.delta1:.3f}, δ2 {m.delta2:.3f}, "
        f"δ3 {m.delta3:.3f}"
    )
    for line in one_sided:
        typer.echo(f"WARNING, --partial: {line}; not scored", err=True)
    typer.echo(f"wrote {out}")


THREADS = typer.Option(2, min=1, max=256, help="Threads for torch.")
CHECKPOINTS = typer.Option(None, help="Folder for per-epoch checkpoints (a rerun resumes).")
DRIVES = typer.Argument(
    ...,
    help="Drive folders (image_02/, and image_03/, depth/, velodyne/, poses.txt as the "
    "supervision needs) or image folders (a student learns on images alone; a right camera or "
    "poses add vista's photometric term).",
)
OUT_MODEL = typer.Option(..., "-o", "--out", help="MODEL.onnx to write.")


def _train(
    data: list[Path],
    out: Path,
    model: Path | None,
    threads: int,
    checkpoints: Path | None,
    params: TrainParams,
) -> None:
    """What `vista depth train` and its old spellings do."""
    from services.depth.train import train_depth

    try:
        trained = train_depth(
            data,
            params,
            out,
            model=model,
            threads=threads,
            checkpoint_dir=checkpoints,
            progress=echo_progress,
        )
    except ValueError as exc:
        fail(str(exc))
    scores = ", ".join(f"{name} {value:.3f}" for name, value in trained.metrics.items())
    typer.echo(
        f"wrote {out} ({trained.architecture}: {scores} on {trained.frames['val']} held-out "
        f"frames; best epoch {trained.best_epoch})"
    )


@depth_app.command("train")
@params_options(TrainParams)
def train_command(
    data: list[Path] = DRIVES,
    out: Path = OUT_MODEL,
    model: Path = typer.Option(
        None,
        "--model",
        help="The teacher (vista's, or any depth model with its spec JSON beside it): a "
        "student's to learn from (needed); a teacher's to adapt (e.g. one trained on the "
        "simulator) instead of starting from scratch.",
    ),
    threads: int = THREADS,
    checkpoints: Path = CHECKPOINTS,
    *,
    params: TrainParams,
) -> None:
    """Train a depth network as the `depth.train` job does. --network teacher: Monodepth2's
    network (ResNet-18 encoder, 14.3 M parameters), self-supervised from stereo, from video
    with a pose network, or both (photometric L1 + SSIM with α = 0.85, edge-aware
    smoothness, per-pixel minimum reprojection, auto-masking), or supervised by depth maps
    or by the LiDAR scans of the drives; with --model, adapts that teacher to your camera
    (e.g. the simulator's, on your own scans or video); writes ONNX with its encoder and
    decoder features as extra outputs (for vista's distillation) and the validation AbsRel.
    --network student: distils the --model teacher into DeepLabv3+ with MobileNetV2 (2.67 M
    parameters) by the thesis's L1 or vista's method; writes ONNX and the student's AbsRel
    against the teacher on held-out images."""
    _train(data, out, model, threads, checkpoints, params)


@depth_app.command(
    "train-teacher",
    hidden=True,
    deprecated=True,
    help="Alias of `vista depth train --network teacher` (kept for this release).",
)
@params_options(TrainParams, fixed={"network": "teacher", "method": "vista"})
def train_teacher_command(
    data: list[Path] = DRIVES,
    out: Path = OUT_MODEL,
    initial: Path = typer.Option(
        None, "--from", help="A teacher to adapt (`vista depth train`'s --model)."
    ),
    threads: int = THREADS,
    checkpoints: Path = CHECKPOINTS,
    *,
    params: TrainParams,
) -> None:
    _train(data, out, initial, threads, checkpoints, params)


@depth_app.command(
    "distill",
    hidden=True,
    deprecated=True,
    help="Alias of `vista depth train --network student` (kept for this release).",
)
@params_options(TrainParams, fixed={"network": "student", "supervision": "depth"})
def distill_command(
    images: list[Path] = DRIVES,
    teacher: Path = typer.Option(
        ..., help="The teacher to learn from (`vista depth train`'s --model)."
    ),
    out: Path = OUT_MODEL,
    threads: int = THREADS,
    checkpoints: Path = CHECKPOINTS,
    *,
    params: TrainParams,
) -> None:
    _train(images, out, teacher, threads, checkpoints, params)


@depth_app.command("predict")
@params_options(PredictParams)
def predict_command(
    images_dir: Path = typer.Argument(
        ..., help="Folder of PNG or JPEG images (or a drive folder: its image_02/)."
    ),
    out_dir: Path = typer.Option(
        ..., "-o", "--out", help="Folder for NAME.png (uint16 m × 256), NAME.color.png, NAME.ply."
    ),
    model_path: Path = typer.Option(
        None,
        "--model",
        help="MODEL.onnx (vista's, or any with its spec JSON); default: the model vista ships "
        "(trained on the simulator, adapted to KITTI's camera by its LiDAR; see the README).",
    ),
    calib: Path = typer.Option(
        None,
        help="calib.json or calib_cam_to_cam.txt (the file, or its folder) for the clouds (default: the drive's, else KITTI's camera).",
    ),
    threads: int = typer.Option(2, min=1, max=256, help="onnxruntime threads."),
    *,
    params: PredictParams,
) -> None:
    """Depth maps at each image's own size in KITTI's convention, colour previews and point
    clouds, as the `depth.predict` job makes them (an int8 model kept as OUT/model.int8.onnx)."""
    from services.depth.predict import image_set, predict_depth

    try:
        done = predict_depth(
            [image_set(images_dir, calib)],
            params,
            out_dir,
            model=model_path,
            threads=threads,
            progress=echo_progress,
        )
    except ValueError as exc:
        fail(str(exc))
    typer.echo(
        f"wrote {len(done.images)} depth maps to {out_dir} ({1000 * done.mean_seconds:.0f} ms a "
        f"frame at {done.width} × {done.height}{', int8' if params.int8 else ''})"
    )


@depth_app.command("import")
def import_command(
    model_path: Path = typer.Argument(
        ..., help="Your ONNX depth model, its spec JSON beside it (same stem)."
    ),
    out: Path = typer.Option(..., "-o", "--out", help="The copy to write, its spec inside."),
) -> None:
    """Copy a depth model of your own with its spec JSON written into the file as vista's
    metadata, so that it can be uploaded as a `model` artifact (a `depth.train` student's
    teacher, or `depth.predict`'s model)."""
    from services.depth.models import stamp_spec

    try:
        spec = stamp_spec(model_path, out)
    except ValueError as exc:
        fail(str(exc))
    typer.echo(f"wrote {out} ({spec.width} × {spec.height} in, {spec.output_kind} out)")


@depth_app.command("build-default")
@params_options(BuildSettings)
def build_default_command(
    out: Path = typer.Option(
        None, "-o", "--out", help="Where to write the model (default: the packaged one)."
    ),
    work: Path = typer.Option(
        Path("bench-results/depth"),
        help="Simulated drives and each stage's model, reused by the next run (and by vista depth bench).",
    ),
    real_drive: Path = typer.Option(
        None, help="A KITTI-raw-layout drive with velodyne/ (default: ../shared/data's drive 0052)."
    ),
    held_out: Path = typer.Option(
        None,
        help="Real frames to score on, never trained on (default: ../shared/data's kitti-object-testing-sample).",
    ),
    *,
    params: BuildSettings,
) -> None:
    """Build the depth model vista ships: a teacher trained on simulated drives, adapted to a
    real camera by that drive's LiDAR (simulated drives mixed in), the student distilled from
    it on real and simulated images, its weights stored in int8 (computed in float), scored
    on the held-out real frames; data, scores, seed, this command and KITTI's licence go into
    its metadata. About an hour on 2 cores at the defaults; each stage is kept in --work."""
    from services.depth.default_model import HELD_OUT, REAL_DRIVE, build_default_model
    from services.depth.models import PACKAGED

    given = params.model_dump(exclude={"threads"})
    options = " ".join(f"--{name.replace('_', '-')} {value}" for name, value in given.items())
    try:
        metadata = build_default_model(
            out or PACKAGED,
            work=work,
            real_drive=real_drive or REAL_DRIVE,
            held_out=held_out or HELD_OUT,
            settings=params,
            command=f"vista depth build-default {options}",
            progress=echo_progress,
        )
    except ValueError as exc:
        fail(str(exc))
    figures = metadata["validation"]
    typer.echo(
        f"wrote {out or PACKAGED}: AbsRel {figures['shipped']['abs_rel']:.3f} on "
        f"{figures['shipped']['frames']} held-out real frames (simulator-only teacher "
        f"{figures['simulator_only_teacher']['abs_rel']:.3f})"
    )


@depth_app.command("bench")
def bench_depth(
    out: Path = typer.Option(Path("bench-results/depth.json"), help="Where to write the JSON."),
    work: Path = typer.Option(
        Path("bench-results/depth"),
        help="Simulated drives and trained models, reused by the next run.",
    ),
    teacher: Path = typer.Option(
        None,
        help="A teacher to distil instead of training one (vista's or any with its spec JSON).",
    ),
    train_drives: int = typer.Option(
        BUILD.sim_drives, min=2, help="Simulated stereo drives of three frames to train on."
    ),
    teacher_epochs: int = typer.Option(BUILD.teacher_epochs, min=1),
    student_epochs: int = typer.Option(BUILD.student_epochs, min=1),
) -> None:
    """The simulator-only teacher and students, the teacher adapted to KITTI's camera by a
    real drive's LiDAR and by its video, the student of the adapted teacher and the shipped
    model side by side: parameters; monodepth2's metrics on held-out simulated frames, on
    KITTI's ten held-out testing frames of other drives and on the adaptation drive (with
    the int8 students and a flat-road prior); latency per 1024 × 320 frame on 1 and 2
    threads for torch, onnxruntime fp32 and int8 (QDQ, QOperator); the thesis's figures
    beside. Trains what the work folder lacks (about 1.5 hours on 2 cores; vista depth
    build-default leaves its stages there) and keeps it."""
    from services.depth.bench import run_depth_bench

    if teacher is not None and not teacher.is_file():
        fail(f"--teacher {teacher}: no such file")
    run_depth_bench(
        out,
        work=work,
        teacher=teacher,
        train_drives=train_drives,
        teacher_epochs=teacher_epochs,
        student_epochs=student_epochs,
    )


def register(app: typer.Typer, simulate_app: typer.Typer, bench_app: typer.Typer) -> None:
    app.add_typer(depth_app, name="depth")
    alias(simulate_app, "depth", simulate, "depth simulate")
    alias(bench_app, "depth", bench_depth, "depth bench")
