"""Job handlers ``tracking.track`` (a LiDAR sequence and the target in; TRACK.json, its plot and, with
labels, the evaluation out), ``tracking.detect`` (a sequence, and camera images as known, in;
DETECTIONS.json and the images with their boxes out) and ``tracking.train`` (labelled
sequences in; an ONNX model and its training history out)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from contract.context import (
    InputArtifact,
    JobContext,
    in_user_words,
    inputs_of_kind,
    one_input,
    store_model,
    unpacked,
)
from contract.errors import JobInputError
from services.tracking.kinds import (
    DETECTIONS,
    DETECTIONS_IMAGE,
    EVALUATION,
    MODEL,
    TRACK_PLOT,
    TRACK_REPORT,
    TRAINING_REPORT,
)

if TYPE_CHECKING:
    import numpy as np

    from services.lib import kitti


def _unpacked(artifact: InputArtifact, folder: Path) -> Path:
    from services.tracking.lidar_archive import extract_lidar

    unpacked(artifact, folder, extract_lidar)
    return folder


def _models(models: list[InputArtifact]) -> dict[str, InputArtifact]:
    """The model inputs by architecture."""
    from services.lib.nn.onnx_io import read_model

    found = {}
    for artifact in models:
        try:
            architecture = read_model(artifact.path).metadata.get("architecture")
        except ValueError as exc:
            raise JobInputError(f"{artifact.label}: {exc}") from exc
        if architecture in found:
            raise JobInputError(f"two `model` inputs are {architecture} models; give one")
        found[architecture] = artifact
    return found


def _tracking_models(ctx: JobContext) -> dict[str, InputArtifact]:
    """The `model` inputs by architecture: the Siamese encoder the tracker needs, the
    learned detector that replaces the shipped one; any other refused."""
    from services.tracking.detect_learned import ARCHITECTURE as DETECTOR
    from services.tracking.siamese import ARCHITECTURE as SIAMESE

    params = ctx.params
    models = _models(inputs_of_kind(ctx, "model"))
    needed = {SIAMESE} if params.tracker == "siamese" else set()
    usable = needed | (
        {DETECTOR} if params.detector == "learned" and params.reset != "never" else set()
    )
    for architecture in needed - set(models):
        what = (
            "the Siamese tracker's encoder" if architecture == SIAMESE else "the learned detector"
        )
        raise JobInputError(
            f"{what} is needed as a `model` input (a tracking.train {architecture} model)"
        )
    for architecture in set(models) - usable:
        raise JobInputError(
            f"the {architecture} model input is not used by these params; leave it out"
        )
    return models


def _store_evaluation(ctx: JobContext, folder: Path, document: dict) -> dict:
    """The run's One-Pass Evaluation against the sequence's labels, when it has them, as an
    artifact; its Success and Precision."""
    from services.tracking.run import evaluate_runs

    if not (folder / "label_02.txt").exists() and not (folder / "label_2").is_dir():
        return {}
    try:
        evaluation = evaluate_runs(folder, [("track.json", document)]).document()
    except ValueError as exc:
        evaluation = {"unmeasured": str(exc)}
    ctx.add_artifact_json(evaluation, kind=EVALUATION.kind, name=EVALUATION.file_name())
    ope = evaluation.get("ope")
    return {"success": ope["success"], "precision": ope["precision"]} if ope else {}


def track_job(ctx: JobContext) -> dict:
    from services.lib.kitti import KittiError
    from services.tracking.detect_learned import ARCHITECTURE as DETECTOR
    from services.tracking.report import plot_run
    from services.tracking.run import run_tracking
    from services.tracking.siamese import ARCHITECTURE as SIAMESE

    sequence = one_input(ctx, "lidar", "the LiDAR sequence")
    models = _tracking_models(ctx)
    ctx.progress(0.01, f"unpacking {sequence.name}")
    folder = _unpacked(sequence, ctx.workdir / "sequence")
    try:
        document = run_tracking(
            folder, ctx.params, threads=ctx.threads,
            siamese_model=models[SIAMESE].path if SIAMESE in models else None,
            detector_model=models[DETECTOR].path if DETECTOR in models else None,
            progress=lambda done, total: ctx.progress(
                0.05 + 0.85 * done / max(total, 1), f"frame {done}/{total}"
            ),
        )  # fmt: skip
    except (ValueError, KittiError) as exc:
        raise JobInputError(in_user_words(str(exc), ctx, [sequence, *models.values()])) from exc
    document["sequence"] = sequence.label
    ctx.progress(0.92, "writing TRACK.json and the plot")
    ctx.add_artifact_json(document, kind=TRACK_REPORT.kind, name=TRACK_REPORT.file_name())
    plot = ctx.workdir / TRACK_PLOT.file_name()
    plot_run(document, plot)
    ctx.add_artifact_file(plot, kind=TRACK_PLOT.kind, name=plot.name, media_type="image/png")
    frames = document["frames"]
    summary = {
        "frames": len(frames),
        "detector_runs": document["detector_runs"],
        "detector_cost_percent": document["detector_cost_percent"],
        "resets": sum(f["reset"] for f in frames),
        "fps": document["fps"],
    }
    summary |= _store_evaluation(ctx, folder, document)
    ctx.progress(1.0, f"{len(frames)} frames, detector on {document['detector_runs']}")
    return summary


def _images_by_frame(images: list[InputArtifact], frames: list[int]) -> dict[int, InputArtifact]:
    """The camera images by the frame their name gives (``0000000042.png``: frame 42)."""
    by_frame: dict[int, InputArtifact] = {}
    for image in images:
        stem = Path(image.name).stem
        if not stem.isdigit():
            raise JobInputError(
                f"{image.label} is not named as a scan: name each camera image as its scan "
                "(0000000042.png for velodyne/0000000042.bin)"
            )
        frame = int(stem)
        if frame not in frames:
            raise JobInputError(f"{image.label}: the sequence has no scan {frame}")
        if frame in by_frame:
            raise JobInputError(
                f"{image.label} and {by_frame[frame].label} are both of scan {frame}"
            )
        by_frame[frame] = image
    return by_frame


def _pictures(ctx: JobContext, frames: list[int]) -> dict[int, tuple[InputArtifact, np.ndarray]]:
    """The camera `image` inputs by the frame their name gives, each read: (input, RGB)."""
    from services.lib.images import read_image

    pictures = {}
    for frame, image in _images_by_frame(inputs_of_kind(ctx, "image"), frames).items():
        try:
            pictures[frame] = (image, read_image(image.path))
        except ValueError as exc:
            raise JobInputError(f"{image.label}: not a readable image") from exc
    return pictures


def _store_drawn(
    ctx: JobContext,
    pictures: dict[int, tuple[InputArtifact, np.ndarray]],
    document: dict,
    calibration: kitti.Calibration,
) -> None:
    """Each camera image with its scan's boxes drawn on it, as an artifact."""
    from services.lib.images import write_image
    from services.tracking.detect import draw_detections

    scans = {scan["frame"]: scan for scan in document["scans"]}
    for frame, (image, picture) in pictures.items():
        name = DETECTIONS_IMAGE.file_name(Path(image.name).stem)
        drawn = ctx.workdir / name
        write_image(drawn, draw_detections(picture, scans[frame], calibration))
        ctx.add_artifact_file(drawn, kind=DETECTIONS_IMAGE.kind, name=name, media_type="image/png")


def detect_job(ctx: JobContext) -> dict:
    from services.lib.kitti import KittiError
    from services.tracking.detect import detect_sequence, detector_for
    from services.tracking.sequence import open_sequence

    sequence_input = one_input(ctx, "lidar", "the LiDAR sequence")
    models = inputs_of_kind(ctx, "model")
    if models and ctx.params.detector != "learned":
        raise JobInputError(
            "a `model` input is the learned detector's: leave it out for the geometric one"
        )
    ctx.progress(0.01, f"unpacking {sequence_input.name}")
    folder = _unpacked(sequence_input, ctx.workdir / "sequence")
    try:
        sequence = open_sequence(folder)
        pictures = _pictures(ctx, sequence.frames)
        document = detect_sequence(
            sequence,
            detector_for(ctx.params, models[0].path if models else None, ctx.threads),
            image_sizes={f: (p.shape[1], p.shape[0]) for f, (_, p) in pictures.items()},
            progress=lambda done, total: ctx.progress(
                0.05 + 0.8 * done / max(total, 1), f"scan {done}/{total}"
            ),
        )
    except (ValueError, KittiError) as exc:
        raise JobInputError(in_user_words(str(exc), ctx, [sequence_input, *models])) from exc
    document = {
        "sequence": sequence_input.label,
        "model": models[0].label if models else None,
    } | document
    ctx.progress(0.88, "writing DETECTIONS.json and the images")
    ctx.add_artifact_json(document, kind=DETECTIONS.kind, name=DETECTIONS.file_name())
    _store_drawn(ctx, pictures, document, sequence.calibration)
    summary = _detections_summary(document)
    ctx.progress(1.0, f"{summary['detections']} cars in {summary['scans']} scans")
    return summary


def _detections_summary(document: dict) -> dict:
    """A DETECTIONS.json's figures: scans, cars found, the time a scan and, with labels,
    recall and precision."""
    summary = {
        "scans": len(document["scans"]),
        "detections": sum(len(scan["scores"]) for scan in document["scans"]),
        "ms_per_scan": document["ms_per_scan"],
    }
    evaluation = document.get("evaluation")
    if evaluation is not None:
        summary |= {
            "recall_near": evaluation["recall_near"],
            "precision_in_view": evaluation["precision_in_view"],
        }
    return summary


def _start_from(ctx: JobContext) -> Path | None:
    """The `model` input a fine-tuning starts from (None: the shipped detector, or none)."""
    given = inputs_of_kind(ctx, "model")
    if given and not ctx.params.fine_tune:
        raise JobInputError("a `model` input is only used with fine_tune: leave it out")
    return given[0].path if given else None


def train_job(ctx: JobContext) -> dict:
    from services.tracking.training import train_network

    sequences = inputs_of_kind(ctx, "lidar")
    if not sequences:
        raise JobInputError("tracking.train needs labelled `lidar` sequences")
    start_from = _start_from(ctx)
    folders = []
    for number, artifact in enumerate(sequences):
        ctx.progress(0.05 * number / len(sequences), f"unpacking {artifact.name}")
        folder = _unpacked(artifact, ctx.workdir / f"sequence-{number}")
        if not (folder / "label_02.txt").exists():
            raise JobInputError(f"{artifact.label} has no label_02.txt: nothing to learn from")
        folders.append(folder)
    model = ctx.workdir / MODEL.file_name()
    try:
        metadata = train_network(
            folders, model, ctx.params, threads=ctx.threads, start_from=start_from,
            checkpoint_dir=ctx.workdir / "checkpoints", sources=[a.label for a in sequences],
            progress=lambda fraction, message: ctx.progress(0.05 + 0.93 * fraction, message),
        )  # fmt: skip
    except ValueError as exc:
        raise JobInputError(in_user_words(str(exc), ctx, sequences)) from exc
    store_model(ctx, model, metadata, model=MODEL, report=TRAINING_REPORT)
    ctx.progress(1.0, f"{metadata['architecture']} trained")
    return {
        "architecture": metadata["architecture"],
        "best_epoch": metadata["training"]["best_epoch"],
    }
