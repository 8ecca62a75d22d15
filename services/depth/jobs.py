"""Job handlers ``depth.train`` (drives or images in; a teacher or a student as an ONNX
model and its training history out) and ``depth.predict`` (a model and images in; depth
maps, previews, point clouds and a report out)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from contract.context import (
    InputArtifact,
    JobContext,
    in_user_words,
    inputs_of_kind,
    store_model,
    unpacked,
)
from contract.errors import JobInputError
from services.depth.drive import IMAGE_SUFFIXES
from services.depth.kinds import (
    CLOUD,
    DEPTH_MAP,
    ERROR_MAP,
    MODEL,
    PREDICT_REPORT,
    PREVIEW,
    TRAINING_REPORT,
)
from services.depth.metrics import METRICS
from services.lib.pointcloud.ply import PLY_MEDIA_TYPE

if TYPE_CHECKING:
    from services.depth.predict import ImageSet, PredictedImage


def _folders(
    ctx: JobContext, artifacts: list[InputArtifact]
) -> list[tuple[InputArtifact | None, Path]]:
    """Each drive archive unpacked to a drive folder, with its artifact; the images together
    in one folder (``images/``, staged as ``<artifact id>-<name>`` so two uploads called
    alike stay apart), with None."""
    from services.depth.drive_archive import extract_drive

    out, images = [], ctx.workdir / "images"
    for number, artifact in enumerate(artifacts):
        if artifact.kind == "drive":
            folder = ctx.workdir / f"drive-{number}"
            unpacked(artifact, folder, extract_drive)
            out.append((artifact, folder))
        else:
            images.mkdir(exist_ok=True)
            suffix = Path(artifact.name).suffix.lower()
            suffix = suffix if suffix in IMAGE_SUFFIXES else ".png"
            shutil.copyfile(
                artifact.path, images / f"{artifact.id:08d}-{Path(artifact.name).stem}{suffix}"
            )
    if images.is_dir():
        out.append((None, images))
    return out


def _user_name(drive: InputArtifact | None, image: Path) -> str:
    """How the user knows a staged image: a drive's frame as ``ARCHIVE-FRAME``, an uploaded
    image by its own name."""
    if drive is not None:
        return f"{Path(drive.name).name.split('.')[0]}-{image.stem}"
    return image.stem.split("-", 1)[1]


def _image_sets(
    groups: list[tuple[InputArtifact | None, Path]], calibration: Path | None
) -> tuple[list[ImageSet], dict[Path, str]]:
    """The staged folders read as the command reads a folder (``predict.image_set``: a
    drive placed by its own calibration, the images by the ``calibration`` input), and
    each image's name as the user knows it."""
    from services.depth.predict import image_set

    sets = [image_set(folder, None if drive else calibration) for drive, folder in groups]
    names = {
        path: _user_name(drive, path)
        for (drive, _), found in zip(groups, sets, strict=True)
        for path in found.images
    }
    return sets, names


def train_job(ctx: JobContext) -> dict:
    from services.depth.train import train_depth
    from services.lib.nn.onnx_io import read_model

    data = inputs_of_kind(ctx, "drive", "image")
    teachers = inputs_of_kind(ctx, "model")
    if len(teachers) > 1:
        raise JobInputError(f"one `model` input at most; got {len(teachers)}")
    ctx.progress(0.01, f"unpacking {len(data)} input{'s' * (len(data) > 1)}")
    folders = [folder for _, folder in _folders(ctx, data)]
    try:
        trained = train_depth(
            folders,
            ctx.params,
            ctx.workdir / MODEL.file_name(),
            model=teachers[0].path if teachers else None,
            inputs=[a.label for a in data],
            model_name=teachers[0].label if teachers else None,
            threads=ctx.threads,
            checkpoint_dir=ctx.workdir / "checkpoints",
            progress=ctx.progress,
        )
    except ValueError as exc:
        raise JobInputError(in_user_words(str(exc), ctx, data + teachers)) from exc
    # the metadata: the spec, the training with its history, the metrics
    metadata = read_model(trained.path).metadata
    store_model(ctx, trained.path, metadata, model=MODEL, report=TRAINING_REPORT)
    scores = ", ".join(f"{k} {v:.4f}" for k, v in trained.metrics.items())
    ctx.progress(1.0, f"{trained.architecture}: {scores}")
    return {"architecture": trained.architecture, **trained.metrics}


def _scored(ctx: JobContext, item: PredictedImage, truth: InputArtifact, stem: str) -> dict:
    """One prediction against its ground truth: the seven metrics (median-scaled, Garg's
    crop) and the error map kept as an output."""
    import cv2

    from services.depth.metrics import evaluate_image
    from services.depth.predict import error_preview
    from services.lib.images import read_image
    from services.lib.kitti import read_depth_png

    gt_m = read_depth_png(truth.path)
    pred_m = read_depth_png(item.depth_path)
    try:
        scored = evaluate_image(gt_m, pred_m, median_scaling=True)
    except ValueError as exc:
        return {"unmeasured": f"{truth.label}: {exc}"}
    path = ctx.workdir / ERROR_MAP.file_name(stem)
    image = read_image(item.image_path)
    cv2.imwrite(str(path), error_preview(gt_m, pred_m, scored.scale, image))
    ctx.add_artifact_file(path, kind=ERROR_MAP.kind, name=path.name, media_type="image/png")
    return {
        **{k: round(v, 4) for k, v in scored.errors.to_json().items()},
        "pixels": scored.pixels,
        "scale": round(scored.scale, 4),
    }


def _kept(ctx: JobContext, item: PredictedImage, stem: str, truth: InputArtifact | None) -> dict:
    """An image's depth map, preview and cloud kept as outputs under the user's name for
    it (``stem``); its entry in the report, scored when it has its ``truth``."""
    ctx.add_artifact_file(
        item.depth_path,
        kind=DEPTH_MAP.kind,
        name=DEPTH_MAP.file_name(stem),
        media_type="image/png",
        meta={"width": item.width, "height": item.height, "unit": "m x 256"},
    )
    ctx.add_artifact_file(
        item.colour_path, kind=PREVIEW.kind, name=PREVIEW.file_name(stem), media_type="image/png"
    )
    if item.cloud_path is not None:
        ctx.add_artifact_file(
            item.cloud_path,
            kind=CLOUD.kind,
            name=CLOUD.file_name(stem),
            media_type=PLY_MEDIA_TYPE,
            meta={"frame": "camera (x right, y down, z forward)"},
        )
    entry = {
        "name": stem,
        "seconds": round(item.seconds, 4),
        "median_depth_m": round(item.median_depth_m, 3),
        "width": item.width,
        "height": item.height,
    }
    if truth is not None:
        entry["evaluation"] = _scored(ctx, item, truth, stem)
    return entry


def _evaluation(entries: list[dict], truths: dict[str, InputArtifact]) -> dict:
    """The report's summary against ground truth: the scored images' mean metrics."""
    import numpy as np

    scored = [e["evaluation"] for e in entries if "abs_rel" in e.get("evaluation", {})]
    means = {m: round(float(np.mean([e[m] for e in scored])), 4) for m in METRICS}
    return {
        "images": len(scored),
        "unmatched_ground_truth": sorted(set(truths) - {e["name"] for e in entries}),
        "median_scaling": True,
        **(means if scored else {}),
    }


def predict_job(ctx: JobContext) -> dict:
    from services.depth.predict import predict_depth

    given = inputs_of_kind(ctx, "model")
    images = inputs_of_kind(ctx, "image", "drive")
    truths = {Path(a.name).stem: a for a in inputs_of_kind(ctx, "depth")}
    calibrations = inputs_of_kind(ctx, "calibration")
    calibration = calibrations[0].path if calibrations else None
    ctx.progress(0.02, f"unpacking {len(images)} input{'s' * (len(images) > 1)}")
    groups = _folders(ctx, images)
    try:
        sets, names = _image_sets(groups, calibration)
        prediction = predict_depth(
            sets,
            ctx.params,
            ctx.workdir / "out",
            model=given[0].path if given else None,
            threads=ctx.threads,
            progress=lambda f, m: ctx.progress(0.05 + 0.9 * f, m),
            shown=names.__getitem__,
        )
        entries = [
            _kept(ctx, item, names[item.image_path], truths.get(names[item.image_path]))
            for item in prediction.images
        ]
    except ValueError as exc:
        every = [*given, *images, *calibrations, *truths.values()]
        raise JobInputError(in_user_words(str(exc), ctx, every)) from exc
    model = prediction.architecture or (given[0].name if given else "vista's shipped model")
    report = {"model": model, "int8": ctx.params.int8, "images": entries}
    if truths:
        report["evaluation"] = _evaluation(entries, truths)
    ctx.add_artifact_json(report, kind=PREDICT_REPORT.kind, name=PREDICT_REPORT.file_name())
    mean_s = prediction.mean_seconds
    ctx.progress(1.0, f"{len(entries)} depth maps, {1000 * mean_s:.0f} ms a frame")
    return {"images": len(entries), "mean_seconds": round(mean_s, 4), "int8": ctx.params.int8}
