"""``vista tracking …``: the LiDAR car-tracking service's commands."""

from __future__ import annotations

from pathlib import Path

import typer
from typer.core import TyperGroup

from contract.cli import alias, echo_progress, fail, params_options, progress_bar
from services.tracking.default_detector import BuildSettings
from services.tracking.kinds import DetectParams, TrackParams, TrainParams

# Heavy imports (numpy, open3d, torch, onnxruntime) stay inside the commands.

OLDER_TRAIN_SPELLINGS = {
    "detector": ["train", "--network", "detector"],
    "siamese": ["train", "--network", "siamese"],
    "default-detector": ["build-default"],
}
"""``vista tracking train WORD …`` → the words of its spelling now (kept for this release)."""


class TrackingCommands(TyperGroup):
    """``vista tracking``'s commands, reading ``train detector|siamese|default-detector …``
    (the older spellings, kept hidden for this release) as ``train --network detector|siamese
    …`` and ``build-default …``: Click cannot make ``train`` a command and a group at once."""

    def resolve_command(
        self, ctx: typer.Context, args: list[str]
    ) -> tuple[str | None, object, list[str]]:
        if args[:1] == ["train"] and len(args) > 1 and args[1] in OLDER_TRAIN_SPELLINGS:
            now = OLDER_TRAIN_SPELLINGS[args[1]]
            typer.secho(
                f"DeprecationWarning: The command 'train {args[1]}' is deprecated: it is "
                f"`vista tracking {' '.join(now)}` now (the old spelling works for this release).",
                fg=typer.colors.RED,
                err=True,
            )
            args = [*now, *args[2:]]
        return super().resolve_command(ctx, args)


track_app = typer.Typer(
    cls=TrackingCommands,
    help="3D single-car tracking on LiDAR (thesis 5.1): simulate KITTI-format drives, detect "
    "cars, track one with detector resets, evaluate by One-Pass Evaluation.",
    no_args_is_help=True,
)


@track_app.command("simulate")
def simulate(
    out_dir: Path = typer.Argument(..., help="The sequence folder to write."),
    frames: int = typer.Option(300, min=1, max=100_000, help="Frames (10 Hz)."),
    cars: int = typer.Option(8, min=1, max=200, help="Moving cars (the first leads the ego car)."),
    seed: int = typer.Option(0, min=0, help="Random seed (street, traffic, sensor noise)."),
    threads: int = typer.Option(2, min=1, max=256, help="Ray-casting threads."),
) -> None:
    """Simulate a drive seen by a 64-beam spinning LiDAR (HDL-64E geometry as KITTI mounted
    it: 64 rings from +2° to −24.9°, 2 048 firings a turn, 10 Hz, range noise, dropout,
    reflectance) ray-cast with Open3D down a random street: cars of four shapes (sedan,
    hatchback, SUV, van) parked and driving, lorries, pedestrians, cyclists, buildings,
    hedges, trees, poles; the ego car follows the first car for the whole drive. Writes
    KITTI tracking's formats: velodyne/NNNNNN.bin, calib.txt, label_02.txt (objects the
    camera sees within 80 m), poses.txt (camera poses, odometry format), and
    simulation.json (each track's shape)."""
    from services.tracking.simulate import simulate_sequence

    with typer.progressbar(length=frames, label="ray casting") as bar:
        summary = simulate_sequence(
            out_dir,
            frames=frames,
            cars=cars,
            seed=seed,
            threads=threads,
            progress=lambda _: bar.update(1),
        )
    typer.echo(
        f"wrote {summary.frames} scans ({summary.points_per_scan:,.0f} points each on average), "
        f"{summary.labels} labels of {summary.tracks} tracks to {out_dir} in {summary.seconds:.0f} s"
    )


INIT_BOX_HELP = "Or start from this box: 'h w l x y z ry' (KITTI camera frame, metres, radians)."


def _camera_box(text: str) -> list[float]:
    from services.tracking.run import parse_camera_box

    return parse_camera_box(text).tolist()


SIAMESE_MODEL = typer.Option(
    None, help="The Siamese tracker's ONNX encoder (vista tracking train --network siamese)."
)
DETECTOR_MODEL = typer.Option(
    None,
    help="A learned detector's ONNX model (vista tracking train; default: the shipped one).",
)
THREADS = typer.Option(2, min=1, max=256, help="Threads for the networks.")


@track_app.command("track")
@params_options(TrackParams, text={"init_box": (INIT_BOX_HELP, _camera_box)})
def track(
    sequence: Path = typer.Argument(
        ...,
        help="A sequence folder: vista's (velodyne/, calib.txt), a KITTI tracking download's training/velodyne/NNNN, or a raw drive.",
    ),
    out: Path = typer.Option(..., "-o", "--out", help="TRACK.json to write."),
    siamese_model: Path = SIAMESE_MODEL,
    detector_model: Path = DETECTOR_MODEL,
    plot: Path = typer.Option(
        None, help="PNG: the target's path, its confidence and the detector's runs."
    ),
    threads: int = THREADS,
    *,
    params: TrackParams,
) -> None:
    """Track one car through a LiDAR sequence: the tracker each frame, the detector when the
    reset policy says so (the target picked among its cars by distance, size and the shape
    the tracker keeps of it, its box fused with the tracker's by their confidences); the
    ego motion from the sequence's poses, or from its scans when it has none.
    TRACK.json has per frame the box in the camera frame (h w l x y z ry) and in the LiDAR
    frame, the confidence, the points in the box, whether the detector ran and reset it;
    and the detector's cost (% of frames) and the frames per second."""
    import json

    from services.lib.kitti import KittiError
    from services.lib.process import prepare_process
    from services.tracking.report import plot_run
    from services.tracking.run import run_tracking

    prepare_process()
    try:
        with progress_bar("tracking") as step:
            document = run_tracking(
                sequence, params, siamese_model=siamese_model, detector_model=detector_model,
                threads=threads, progress=lambda done, total: step(done / max(total, 1)),
            )  # fmt: skip
    except (ValueError, KittiError) as exc:
        fail(str(exc))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(document, indent=1) + "\n")
    if plot is not None:
        plot_run(document, plot)
    frames = document["frames"]
    typer.echo(
        f"{len(frames)} frames, detector on {document['detector_runs']} ({document['detector_cost_percent']:.1f} %), "
        f"{sum(f['reset'] for f in frames)} resets, mean confidence {sum(f['confidence'] for f in frames) / len(frames):.2f}, "
        f"{document['fps']:.0f} frames/s; wrote {out}"
    )


alias(track_app, "run", track, "tracking track")


@track_app.command("eval")
def evaluate(
    sequence: Path = typer.Argument(..., help="The labelled sequence the runs tracked in."),
    tracks: list[Path] = typer.Argument(..., help="TRACK.json files (vista tracking track)."),
    out: Path = typer.Option(..., "-o", "--out", help="EVAL.json to write."),
    plot: Path = typer.Option(None, help="PNG of the success and precision curves."),
) -> None:
    """One-Pass Evaluation as SC3D and P2B compute it: per frame the 3D IoU with the label
    and the centre distance; Success = area under the share of frames with IoU ≥ t (t over
    0–1), Precision = area under the share with error ≤ e (e over 0–2 m), pooled over the
    runs' frames, in percent; each run's own figures beside."""
    import json

    from services.lib.kitti import KittiError
    from services.tracking.report import plot_ope, read_track
    from services.tracking.run import evaluate_runs

    try:
        documents = [(str(path), read_track(path)) for path in tracks]
        result = evaluate_runs(sequence, documents)
    except (ValueError, KittiError) as exc:
        fail(str(exc))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result.document(), indent=1) + "\n")
    if plot is not None:
        plot_ope({"pooled": result.pooled}, plot)
    typer.echo(
        f"{result.pooled.tracklets} run(s), {result.pooled.frames} frames: Success {result.pooled.success:.2f}, "
        f"Precision {result.pooled.precision:.2f}; wrote {out}"
    )


@track_app.command("detect")
@params_options(DetectParams)
def detect(
    scan: Path = typer.Argument(
        ..., help="A scan (.bin), or a folder of them (a KITTI object velodyne/)."
    ),
    calib: Path = typer.Option(
        ..., help="Its calibration file, or the folder of them (calib/NNNNNN.txt)."
    ),
    out: Path = typer.Option(
        ..., "-o", "--out", help="label_2 file to write (a folder when SCAN is one)."
    ),
    detector_model: Path = DETECTOR_MODEL,
    labels: Path = typer.Option(
        None, help="label_2 folder (or file) to score the detections against."
    ),
    threads: int = THREADS,
    *,
    params: DetectParams,
) -> None:
    """Cars in LiDAR scans as KITTI label_2 lines (type Car, truncation and occlusion −1,
    alpha, the 2D box in image 2, h w l, the bottom centre x y z in the rectified camera
    frame, rotation_y, the score as the 16th field) — the cars in the camera's view, as
    KITTI's labels are. With --labels, their recall within 40 m (BEV IoU ≥ 0.5) and precision
    in the camera's view."""
    from services.lib.process import prepare_process
    from services.tracking.detect import detect_files

    prepare_process()
    try:
        summary = detect_files(
            scan, calib, out, params, model=detector_model, labels=labels, threads=threads
        )
    except ValueError as exc:
        fail(str(exc))
    typer.echo(summary)


@track_app.command("train")
@params_options(TrainParams)
def train(
    data: list[Path] = typer.Argument(
        ...,
        help="Labelled sequence folders (vista tracking simulate, KITTI tracking) or, for the detector, KITTI object folders (velodyne/, calib/, label_2/).",
    ),
    out: Path = typer.Option(
        ..., "-o", "--out", help="MODEL.onnx to write: the detector, or the Siamese encoder."
    ),
    start_from: Path = typer.Option(
        None,
        "--from",
        help="Fine-tune this detector (vista's shipped one, or one you trained; sets "
        "--fine-tune): a few of your labelled scans adapt it to your sensor in minutes.",
    ),
    validate: list[Path] = typer.Option(
        None,
        help="detector: labelled folders held out for validation (repeatable): the model is "
        "scored on them before and after, and nothing is chosen on them. Default: a tenth of DATA.",
    ),
    paste_cars_from: list[Path] = typer.Option(
        None,
        help="detector: labelled folders whose cars are also pasted into the training scans "
        "(repeatable; the training scans' own cars always are).",
    ),
    threads: int = THREADS,
    checkpoints: Path = typer.Option(
        None, help="Folder for per-epoch checkpoints (a rerun resumes)."
    ),
    *,
    params: TrainParams,
) -> None:
    """Train one of the service's networks on labelled scans and export it as ONNX with its
    data, seed, licence and validation in the metadata. The detector (--network detector,
    the default: BEV, PIXOR/CenterPoint-style, 0.62 M parameters) learns from KITTI object
    folders, labelled sequences (label_02.txt, or a drive's label_2/ folder) or vista's
    simulations, with cars cut from labelled scans pasted into others; with --fine-tune (or
    --from) it fine-tunes a model instead (its batch norms folded, a smaller step) and
    reports the validation scans' recall and precision before and after. SC3D's Siamese
    PointNet (--network siamese) learns from the car tracklets of labelled sequences (cosine
    similarity regressed to a Gaussian of the candidate's offset, with the shape-completion
    regulariser); its encoder is exported."""
    import shlex
    import sys

    from services.lib.process import prepare_process
    from services.tracking.training import train_network

    prepare_process()
    if start_from is not None:
        params = params.model_copy(update={"fine_tune": True})
    try:
        metadata = train_network(
            data, out, params, threads=threads, start_from=start_from,
            validate_on=validate or None, paste_from=paste_cars_from or None,
            checkpoint_dir=checkpoints, progress=echo_progress,
            command=shlex.join(["vista", *sys.argv[1:]]),
        )  # fmt: skip
    except ValueError as exc:
        fail(str(exc))
    if params.network == "siamese":
        mse = metadata["training"]["validation_similarity_mse"]
        typer.echo(f"validation similarity MSE {mse}; wrote {out}")
        return
    scores = metadata["validation"]
    before = scores.get("before_fine_tuning")
    if before is not None:
        typer.echo(f"before: {_scores_line(before)}")
    typer.echo(
        f"{'after' if before is not None else 'validation'}: {_scores_line(scores)}; wrote {out}"
    )


def _scores_line(scores: dict) -> str:
    from services.tracking.detection_eval import ratio_text

    return (
        f"{scores['scans']} scans, recall within 40 m {ratio_text(scores['found_near'], scores['cars_near'])}, "
        f"precision in view {ratio_text(scores['true_positives'], scores['true_positives'] + scores['false_positives'])}"
    )


@track_app.command("build-default")
@params_options(BuildSettings)
def build_default(
    out: Path = typer.Option(
        None, "-o", "--out", help="Where to write the detector (default: the shipped one)."
    ),
    work: Path = typer.Option(
        Path("bench-results/tracking"),
        help="Simulated drives and the simulator-only model, kept and reused (also vista tracking bench's).",
    ),
    real: Path = typer.Option(
        None,
        help="KITTI labelled object scans to fine-tune on (default ../shared/data/kitti-object-sample).",
    ),
    held_out: Path = typer.Option(
        None,
        help="A labelled real drive never trained on, to validate on (default ../shared/data/kitti-raw-2011_09_26_drive_0048).",
    ),
    *,
    params: BuildSettings,
) -> None:
    """Build vista's shipped car detector as it ships, seeded: simulated drives (40 of 60
    frames), a detector trained on them (the simulator-only model), fine-tuned on KITTI's
    labelled object scans with cars pasted from them and from the drives, validated on a
    real drive it never saw; the metadata names the data, the seed, this command and
    KITTI's licence (CC BY-NC-SA 3.0). About half an hour on 2 cores from an empty work
    folder; each step is kept in --work."""
    from services.lib.process import prepare_process
    from services.tracking.default_detector import REAL_HELD_OUT, REAL_TRAIN, build_default_detector
    from services.tracking.detect_learned import DEFAULT_MODEL

    prepare_process()
    try:
        metadata = build_default_detector(
            work, out or DEFAULT_MODEL, real=real or REAL_TRAIN,
            held_out=held_out or REAL_HELD_OUT, settings=params, say=typer.echo,
        )  # fmt: skip
    except ValueError as exc:
        fail(str(exc))
    typer.echo(f"held out: {_scores_line(metadata['validation'])}; wrote {out or DEFAULT_MODEL}")


@track_app.command("bench")
def bench_tracking(
    out: Path = typer.Option(
        Path("bench-results/tracking.json"),
        help="Where to write the JSON (and the OPE curves beside it as PNG).",
    ),
    work: Path = typer.Option(
        Path("bench-results/tracking"),
        help="Simulated drives and trained models, reused by the next run.",
    ),
    detector_model: Path = typer.Option(
        None, help="A learned detector to use instead of training one."
    ),
    siamese_model: Path = typer.Option(
        None, help="A Siamese encoder to use instead of training one."
    ),
    test_drives: int = typer.Option(
        4, min=1, max=100, help="Long simulated test drives (400 frames each)."
    ),
) -> None:
    """The thesis's Table 5.1 re-run on simulated long tracklets — the Siamese tracker with
    the learned detector at the fixed reset frequencies 1 … 1/100 and never — with vista's
    adaptive resets at 5 and 10 % budgets beside, the same sweep for the geometric tracker;
    each tracker's frames per second alone and the whole pipeline's; both detectors'
    recall and precision on KITTI's real labelled scans and on simulated ones. Trains what
    the work folder lacks (about an hour on 2 cores) and keeps it."""
    from services.tracking.bench import run_tracking_bench

    for given in (detector_model, siamese_model):
        if given is not None and not given.is_file():
            fail(f"{given}: no such model file")
    run_tracking_bench(
        out,
        work=work,
        detector_model=detector_model,
        siamese_model=siamese_model,
        test_drives=test_drives,
    )


def register(app: typer.Typer, simulate_app: typer.Typer, bench_app: typer.Typer) -> None:
    app.add_typer(track_app, name="tracking")
    app.add_typer(
        track_app,
        name="track",
        hidden=True,
        deprecated=True,
        help="Alias of `vista tracking` (kept for this release).",
    )
    alias(simulate_app, "tracking", simulate, "tracking simulate")
    alias(bench_app, "tracking", bench_tracking, "tracking bench")
