"""Job handlers ``tracking.track`` (a LiDAR sequence and the target in; TRACK.json, its plot and, with
labels, the evaluation out), ``tracking.detect`` (a sequence, and camera images as known, in;
DETECTIONS.json and the images with their boxes out) and ``tracking.train`` (labelled
sequences in; an ONNX model and its training history out)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
    DETECTOR_EPOCHS,
    EVALUATION,
    FINE_TUNE_EPOCHS,
    FINE_TUNE_LEARNING_RATE,
    MODEL,
    SIAMESE_EPOCHS,
    TRACK_PLOT,
    TRACK_REPORT,
    TRAINING_REPORT,
)


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


def track_job(ctx: JobContext) -> dict:
    from services.lib.kitti import KittiError
    from services.tracking.detect_learned import ARCHITECTURE as DETECTOR
    from services.tracking.report import plot_run
    from services.tracking.run import evaluate_runs, run_tracking
    from services.tracking.siamese import ARCHITECTURE as SIAMESE

    params = ctx.params
    sequence = one_input(ctx, "lidar", "the LiDAR sequence")
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
    ctx.progress(0.01, f"unpacking {sequence.name}")
    folder = _unpacked(sequence, ctx.workdir / "sequence")
    try:
        document = run_tracking(
            folder,
            track_id=params.track_id,
            init_box=np.array(params.init_box) if params.init_box is not None else None,
            start_frame=params.start_frame,
            end_frame=params.end_frame,
            tracker=params.tracker,
            detector=params.detector,
            reset=params.reset,
            siamese_model=models[SIAMESE].path if SIAMESE in models else None,
            detector_model=models[DETECTOR].path if DETECTOR in models else None,
            threads=ctx.threads,
            progress=lambda done, total: ctx.progress(
                0.05 + 0.85 * done / max(total, 1), f"frame {done}/{total}"
            ),
        )
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
    if (folder / "label_02.txt").exists() or (folder / "label_2").is_dir():
        try:
            evaluation = evaluate_runs(folder, [("track.json", document)]).document()
        except ValueError as exc:
            evaluation = {"unmeasured": str(exc)}
        ctx.add_artifact_json(evaluation, kind=EVALUATION.kind, name=EVALUATION.file_name())
        if "ope" in evaluation:
            summary |= {
                "success": evaluation["ope"]["success"],
                "precision": evaluation["ope"]["precision"],
            }
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


def detect_job(ctx: JobContext) -> dict:
    from services.lib.images import read_image, write_image
    from services.lib.kitti import KittiError
    from services.tracking.detect import detect_sequence, draw_detections
    from services.tracking.run import make_detector
    from services.tracking.sequence import open_sequence

    params = ctx.params
    sequence_input = one_input(ctx, "lidar", "the LiDAR sequence")
    models = inputs_of_kind(ctx, "model")
    if models and params.detector != "learned":
        raise JobInputError(
            "a `model` input is the learned detector's: leave it out for the geometric one"
        )
    ctx.progress(0.01, f"unpacking {sequence_input.name}")
    folder = _unpacked(sequence_input, ctx.workdir / "sequence")
    given = [sequence_input, *models]
    try:
        sequence = open_sequence(folder)
        images = _images_by_frame(inputs_of_kind(ctx, "image"), sequence.frames)
        pictures = {}
        for frame, image in images.items():
            try:
                pictures[frame] = read_image(image.path)
            except ValueError as exc:
                raise JobInputError(f"{image.label}: not a readable image") from exc
        detector = make_detector(params.detector, models[0].path if models else None, ctx.threads)
        if params.threshold is not None:
            detector.threshold = params.threshold
        document = detect_sequence(
            sequence,
            detector,
            image_sizes={f: (p.shape[1], p.shape[0]) for f, p in pictures.items()},
            progress=lambda done, total: ctx.progress(
                0.05 + 0.8 * done / max(total, 1), f"scan {done}/{total}"
            ),
        )
    except (ValueError, KittiError) as exc:
        raise JobInputError(in_user_words(str(exc), ctx, given)) from exc
    document = {
        "sequence": sequence_input.label,
        "model": models[0].label if models else None,
    } | document
    ctx.progress(0.88, "writing DETECTIONS.json and the images")
    ctx.add_artifact_json(document, kind=DETECTIONS.kind, name=DETECTIONS.file_name())
    scans = {scan["frame"]: scan for scan in document["scans"]}
    for frame, picture in pictures.items():
        name = DETECTIONS_IMAGE.file_name(Path(images[frame].name).stem)
        drawn = ctx.workdir / name
        write_image(drawn, draw_detections(picture, scans[frame], sequence.calibration))
        ctx.add_artifact_file(drawn, kind=DETECTIONS_IMAGE.kind, name=name, media_type="image/png")
    found = sum(len(scan["scores"]) for scan in document["scans"])
    summary = {
        "scans": len(scans),
        "detections": found,
        "ms_per_scan": document["ms_per_scan"],
    }
    evaluation = document.get("evaluation")
    if evaluation is not None:
        summary |= {
            "recall_near": evaluation["recall_near"],
            "precision_in_view": evaluation["precision_in_view"],
        }
    ctx.progress(1.0, f"{found} cars in {len(scans)} scans")
    return summary


def _starting_detector(ctx: JobContext, params: object) -> str | None:
    """The detector a fine-tuning starts from (None: from scratch)."""
    from services.tracking.detect_learned import DEFAULT_MODEL

    given = inputs_of_kind(ctx, "model")
    if not params.fine_tune:
        if given:
            raise JobInputError("a `model` input is only used with fine_tune: leave it out")
        return None
    if params.network != "detector":
        raise JobInputError("fine_tune applies to the detector, not to the Siamese encoder")
    if given:
        return str(given[0].path)
    if not DEFAULT_MODEL.is_file():
        raise JobInputError(
            "this installation lacks vista's shipped detector: give a `model` input"
        )
    return str(DEFAULT_MODEL)


def train_job(ctx: JobContext) -> dict:
    from services.tracking.detector_training import DetectorTrainConfig, train_detector
    from services.tracking.siamese import SiameseTrainConfig, train_siamese

    params = ctx.params
    sequences = inputs_of_kind(ctx, "lidar")
    if not sequences:
        raise JobInputError("tracking.train needs labelled `lidar` sequences")
    folders = []
    for number, artifact in enumerate(sequences):
        ctx.progress(0.05 * number / len(sequences), f"unpacking {artifact.name}")
        folder = _unpacked(artifact, ctx.workdir / f"sequence-{number}")
        if not (folder / "label_02.txt").exists():
            raise JobInputError(f"{artifact.label} has no label_02.txt: nothing to learn from")
        folders.append(folder)
    settings = {"seed": params.seed, "threads": ctx.threads, "device": params.device}
    start = _starting_detector(ctx, params)
    if params.learning_rate is not None:
        settings["learning_rate"] = params.learning_rate
    elif start is not None:
        settings["learning_rate"] = FINE_TUNE_LEARNING_RATE
    model = ctx.workdir / MODEL.file_name()
    options = {
        "checkpoint_dir": ctx.workdir / "checkpoints",
        "progress": lambda fraction, message: ctx.progress(0.05 + 0.93 * fraction, message),
        "sources": [a.label for a in sequences],
    }
    try:
        if params.network == "detector":
            epochs = params.epochs or (FINE_TUNE_EPOCHS if start else DETECTOR_EPOCHS)
            config = DetectorTrainConfig(epochs=epochs, initial=start, **settings)
            metadata = train_detector(folders, model, config, **options)
        else:
            config = SiameseTrainConfig(epochs=params.epochs or SIAMESE_EPOCHS, **settings)
            metadata = train_siamese(folders, model, config, **options)
    except ValueError as exc:
        raise JobInputError(in_user_words(str(exc), ctx, sequences)) from exc
    store_model(ctx, model, metadata, model=MODEL, report=TRAINING_REPORT)
    ctx.progress(1.0, f"{metadata['architecture']} trained")
    return {
        "architecture": metadata["architecture"],
        "best_epoch": metadata["training"]["best_epoch"],
    }
