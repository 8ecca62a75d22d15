"""Job handlers ``tracking.track`` (a LiDAR sequence and the target in; TRACK.json, its plot and, with
labels, the evaluation out) and ``tracking.train`` (labelled sequences in; an ONNX model and its
training history out)."""

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
    if (folder / "label_02.txt").exists():
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
