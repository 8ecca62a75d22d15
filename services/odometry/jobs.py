"""Job handlers ``odometry.run`` (a frame sequence in; trajectory, report, plot and, with the
truth, the evaluation out) and ``odometry.train`` (sequences with truth in; an ONNX model
and its training history out)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from contract.context import (
    InputArtifact,
    JobContext,
    inputs_of_kind,
    one_input,
    store_model,
    unpacked,
)
from contract.errors import JobInputError
from services.odometry.kinds import (
    EVALUATION,
    MODEL,
    RUN_REPORT,
    TRAINING_REPORT,
    TRAJECTORY,
    TRAJECTORY_PLOT,
)
from services.odometry.sequence import SequenceArchive, extract_sequence

if TYPE_CHECKING:
    from services.odometry.run import OdometryRun
    from services.odometry.tum import Trajectory2D

TUM_MEDIA_TYPE = "text/plain"


def _named(
    message: str,
    sequence: InputArtifact,
    found: SequenceArchive,
    folder: Path,
    models: list[InputArtifact],
) -> str:
    """An error about the unpacked files in the user's names: the artifact and the frame's
    name in the archive, the model artifact."""
    frames = re.escape(str(folder / "frames")) + r"/(\d+)\.png"
    message = re.sub(
        frames,
        lambda m: f"{sequence.label}: {found.frames[int(m[1])]}",
        message,
    )
    message = message.replace(str(folder / "frames"), sequence.label)
    for model in models:
        message = message.replace(str(model.path), model.label)
    return message


def _model_inputs(ctx: JobContext, method: str) -> list[InputArtifact]:
    """The `model` input: OE-Net's, which method oenet needs and the others refuse."""
    models = inputs_of_kind(ctx, "model")
    if method == "oenet" and not models:
        raise JobInputError(
            "method oenet needs a `model` input: an OE-Net built by an `odometry.train` step "
            "or `vista odometry train` (method vista needs none)"
        )
    if method != "oenet" and models:
        raise JobInputError(f"method {method} uses no model; leave the `model` input out")
    return models


def _store_run(ctx: JobContext, result: OdometryRun, truth: Trajectory2D | None) -> None:
    """The trajectory, its report and its plot as the job's artifacts."""
    from services.odometry.report import write_run

    out = ctx.workdir / "out"
    out.mkdir()
    paths = [out / o.file_name() for o in (TRAJECTORY, RUN_REPORT, TRAJECTORY_PLOT)]
    write_run(result, *paths, truth)
    for output, path, media_type in zip(
        (TRAJECTORY, RUN_REPORT, TRAJECTORY_PLOT),
        paths,
        (TUM_MEDIA_TYPE, "application/json", "image/png"),
        strict=True,
    ):
        ctx.add_artifact_file(path, kind=output.kind, name=path.name, media_type=media_type)


def _store_evaluation(ctx: JobContext, result: OdometryRun, truth: Trajectory2D) -> dict:
    """The run against the truth (as `vista odometry eval` scores it, with the error along
    the path) as an artifact; its scores."""
    from services.odometry.evaluate import error_along_path, evaluate

    scores = evaluate(result.trajectory, truth, result.covariance[-1]).document()
    along = {"along_path": error_along_path(result.trajectory, truth)}
    ctx.add_artifact_json(scores | along, kind=EVALUATION.kind, name=EVALUATION.file_name())
    return scores


def odometry_job(ctx: JobContext) -> dict:
    from services.odometry.run import run_odometry
    from services.odometry.tum import read_tum

    params = ctx.params
    sequence = one_input(ctx, "frames", "the frame sequence")
    models = _model_inputs(ctx, params.method)
    ctx.progress(0.01, f"unpacking {sequence.name}")
    folder = ctx.workdir / "sequence"
    found = unpacked(sequence, folder, extract_sequence)
    truth = read_tum(folder / "truth.tum") if found.truth_member else None
    try:
        result = run_odometry(
            folder / "frames",
            found.camera,
            params,
            model=models[0].path if models else None,
            threads=ctx.threads,
            progress=lambda fraction, message: ctx.progress(0.05 + 0.85 * fraction, message),
        )
    except ValueError as exc:
        raise JobInputError(_named(str(exc), sequence, found, folder, models)) from exc
    ctx.progress(0.92, "writing the trajectory")
    _store_run(ctx, result, truth)
    summary = {
        "method": params.method,
        "frames": len(result.trajectory),
        "pairs_per_s": round(result.pairs_per_s, 1),
        "flagged": result.flagged,
        "warned": result.warned,
        "final_sigma_xy_mm": round(float(result.sigma_xy_mm[-1]), 3),
    }
    if truth is not None:
        summary["evaluation"] = _store_evaluation(ctx, result, truth)
    ctx.progress(
        1.0,
        f"{len(result.steps.motion)} pairs, {result.flagged} flagged, {result.warned} warned",
    )
    return summary


def train_job(ctx: JobContext) -> dict:
    from contract.training import config_from
    from services.lib.nn.regression import TrainConfig
    from services.odometry.oenet import train_oenet, training_summary

    params = ctx.params
    sequences = inputs_of_kind(ctx, "frames")
    if not sequences:
        raise JobInputError("odometry.train needs at least one `frames` sequence with truth.tum")
    folders = []
    for number, artifact in enumerate(sequences):
        ctx.progress(0.1 * number / len(sequences), f"unpacking {artifact.name}")
        folder = ctx.workdir / f"sequence-{number}"
        if unpacked(artifact, folder, extract_sequence).truth_member is None:
            raise JobInputError(
                f"{artifact.label} has no truth.tum: training needs each pair's true motion"
            )
        folders.append(folder)
    config = config_from(TrainConfig, params, threads=ctx.threads)
    model = ctx.workdir / MODEL.file_name()
    try:
        metadata = train_oenet(
            folders,
            model,
            config,
            checkpoint_dir=ctx.workdir / "checkpoints",
            sources=[a.label for a in sequences],
            progress=lambda fraction, message: ctx.progress(0.1 + 0.88 * fraction, message),
        )
    except ValueError as exc:
        raise JobInputError(str(exc).replace(str(ctx.workdir), "the job's folder")) from exc
    store_model(ctx, model, metadata, model=MODEL, report=TRAINING_REPORT)
    ctx.progress(1.0, training_summary(metadata))
    return {"architecture": metadata["architecture"], **metadata["metrics"]}
