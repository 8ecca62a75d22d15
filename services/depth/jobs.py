"""Job handlers ``depth.train`` (drives or images in; a teacher or a student as an ONNX
model and its training history out) and ``depth.predict`` (a model and images in; depth
maps, previews, point clouds and a report out)."""

from __future__ import annotations

import shutil
from pathlib import Path

from contract.context import (
    InputArtifact,
    JobContext,
    in_user_words,
    inputs_of_kind,
    store_model,
    unpacked,
)
from contract.errors import JobInputError
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


def _folders(ctx: JobContext, artifacts: list[InputArtifact]) -> list[tuple[InputArtifact, Path]]:
    """Each drive archive unpacked to a drive folder; the images together in one folder
    (``images/``, named by artifact so two uploads called alike stay apart)."""
    from services.depth.drive_archive import extract_drive

    out, images = [], ctx.workdir / "images"
    for number, artifact in enumerate(artifacts):
        if artifact.kind == "drive":
            folder = ctx.workdir / f"drive-{number}"
            unpacked(artifact, folder, extract_drive)
            out.append((artifact, folder))
        else:
            images.mkdir(exist_ok=True)
            suffix = (
                Path(artifact.name).suffix.lower()
                if Path(artifact.name).suffix.lower() in (".png", ".jpg", ".jpeg")
                else ".png"
            )
            shutil.copyfile(
                artifact.path, images / f"{artifact.id:08d}-{Path(artifact.name).stem}{suffix}"
            )
    if images.is_dir():
        out.append((None, images))
    return out


def train_job(ctx: JobContext) -> dict:
    from contract.training import config_from
    from services.depth.data import load_frames
    from services.depth.distill import STUDENT_ARCHITECTURE, distill, save_student
    from services.depth.models import DepthModel
    from services.depth.teacher import TEACHER_ARCHITECTURE, save_teacher, train_teacher
    from services.depth.training import DepthTrainConfig
    from services.lib.nn.onnx_io import read_model

    params = ctx.params
    data = inputs_of_kind(ctx, "drive", "image")
    teachers = inputs_of_kind(ctx, "model")
    if params.network == "student" and not teachers:
        raise JobInputError(
            "network student needs the teacher as a `model` input (a depth.train teacher's, or your own ONNX with vista's metadata)"
        )
    if len(teachers) > 1:
        raise JobInputError(f"one `model` input at most; got {len(teachers)}")
    ctx.progress(0.01, f"unpacking {len(data)} input{'s' * (len(data) > 1)}")
    folders = _folders(ctx, data)
    config = config_from(DepthTrainConfig, params, threads=ctx.threads)
    say = lambda fraction, message: ctx.progress(0.1 + 0.85 * fraction, message)  # noqa: E731 - a one-line adapter
    path = ctx.workdir / MODEL.file_name()
    inputs = [a.label for a in data]
    size = {"width": params.width, "height": params.height}
    try:
        frames = load_frames(
            [folder for _, folder in folders],
            params.width,
            params.height,
            lidar=params.network == "teacher" and params.supervision == "lidar",
            progress=lambda f, m: ctx.progress(0.02 + 0.08 * f, m),
        )
        if params.network == "teacher":
            result = train_teacher(
                frames,
                params.supervision,
                config,
                initial=teachers[0].path if teachers else None,
                checkpoint_dir=ctx.workdir / "checkpoints",
                progress=say,
            )
            ctx.progress(0.96, "exporting to ONNX")
            adapted = {"adapted_from": teachers[0].label} if teachers else {}
            metrics = save_teacher(result, path, config, **size, inputs=inputs, **adapted)
            architecture = TEACHER_ARCHITECTURE
        else:
            teacher = DepthModel(teachers[0].path, ctx.threads)
            result = distill(
                teacher,
                frames,
                params.method,
                config,
                checkpoint_dir=ctx.workdir / "checkpoints",
                progress=say,
            )
            ctx.progress(0.96, "exporting to ONNX")
            metrics = save_student(
                result,
                path,
                config,
                **size,
                teacher=teachers[0].label,
                inputs=inputs,
            )
            architecture = STUDENT_ARCHITECTURE
    except ValueError as exc:
        raise JobInputError(in_user_words(str(exc), ctx, data + teachers)) from exc
    # the metadata: the spec, the training with its history, the metrics
    store_model(ctx, path, read_model(path).metadata, model=MODEL, report=TRAINING_REPORT)
    ctx.progress(1.0, f"{architecture}: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
    return {"architecture": architecture, **metrics}


def _scored(ctx: JobContext, item, image: Path, truth: InputArtifact, stem: str) -> dict:  # noqa: ANN001
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
    cv2.imwrite(str(path), error_preview(gt_m, pred_m, scored.scale, read_image(image)))
    ctx.add_artifact_file(path, kind=ERROR_MAP.kind, name=path.name, media_type="image/png")
    return {
        **{k: round(v, 4) for k, v in scored.errors.to_json().items()},
        "pixels": scored.pixels,
        "scale": round(scored.scale, 4),
    }


def predict_job(ctx: JobContext) -> dict:
    import numpy as np

    from services.depth.data import image_files
    from services.depth.default_model import default_model
    from services.depth.drive import read_calibration, read_calibration_file
    from services.depth.models import DepthModel
    from services.depth.predict import predict_folder, resize_for
    from services.depth.quantize import quantize_int8
    from services.lib.images import read_image

    given = inputs_of_kind(ctx, "model")
    images = inputs_of_kind(ctx, "image", "drive")
    truths = {Path(a.name).stem: a for a in inputs_of_kind(ctx, "depth")}
    calibrations = inputs_of_kind(ctx, "calibration")
    calibration = calibrations[0] if calibrations else None
    try:
        model = DepthModel(given[0].path if given else default_model(), ctx.threads)
    except ValueError as exc:
        raise JobInputError(in_user_words(str(exc), ctx, given)) from exc
    model_name = given[0].name if given else "vista's shipped model"
    ctx.progress(0.02, f"unpacking {len(images)} input{'s' * (len(images) > 1)}")
    groups = _folders(ctx, images)
    out = ctx.workdir / "out"
    report = {
        "model": model.spec.metadata.get("architecture", model_name),
        "int8": ctx.params.int8,
        "images": [],
    }
    try:
        if ctx.params.int8:
            paths = [
                p
                for _, folder in groups
                for p in image_files(
                    folder / "image_02" if (folder / "image_02").is_dir() else folder
                )
            ]
            sample = np.stack(
                [resize_for(model, read_image(p)) for p in paths[:: max(1, len(paths) // 32)]]
            )
            model = DepthModel(
                quantize_int8(model, sample, ctx.workdir / "model.int8.onnx", operators=True),
                ctx.threads,
            )
        for number, (artifact, folder) in enumerate(groups):
            drive = artifact is not None
            paths = image_files(folder / "image_02") if drive else image_files(folder)
            camera = None
            if drive or calibration is not None:
                first = read_image(paths[0])
                size = (first.shape[1], first.shape[0])
                camera = (
                    read_calibration(folder, size)
                    if drive
                    else read_calibration_file(calibration.path, size)
                )
            target = out / f"group-{number}"
            done = predict_folder(
                model,
                paths,
                target,
                camera=camera,
                clouds=ctx.params.clouds,
                progress=lambda f, m, n=number: ctx.progress(0.05 + 0.9 * (n + f) / len(groups), m),
                shown=(
                    (lambda p, a=artifact: f"{a.name} {p.name}")
                    if drive
                    else (lambda p: p.name.split("-", 1)[1])  # staged as <artifact id>-<name>
                ),
            )
            for item, source in zip(done, paths, strict=True):
                stem = (
                    f"{Path(artifact.name).name.split('.')[0]}-{item.name}"
                    if drive
                    else item.name.split("-", 1)[1]
                )
                ctx.add_artifact_file(
                    item.depth_path,
                    kind=DEPTH_MAP.kind,
                    name=DEPTH_MAP.file_name(stem),
                    media_type="image/png",
                    meta={"width": item.width, "height": item.height, "unit": "m x 256"},
                )
                ctx.add_artifact_file(
                    item.colour_path,
                    kind=PREVIEW.kind,
                    name=PREVIEW.file_name(stem),
                    media_type="image/png",
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
                if stem in truths:
                    entry["evaluation"] = _scored(ctx, item, source, truths[stem], stem)
                report["images"].append(entry)
    except ValueError as exc:
        raise JobInputError(
            in_user_words(str(exc), ctx, [*given, *images, *calibrations, *truths.values()])
        ) from exc
    scored = [i["evaluation"] for i in report["images"] if "abs_rel" in i.get("evaluation", {})]
    if truths:
        report["evaluation"] = {
            "images": len(scored),
            "unmatched_ground_truth": sorted(set(truths) - {i["name"] for i in report["images"]}),
            "median_scaling": True,
            **(
                {m: round(float(np.mean([e[m] for e in scored])), 4) for m in METRICS}
                if scored
                else {}
            ),
        }
    ctx.add_artifact_json(report, kind=PREDICT_REPORT.kind, name=PREDICT_REPORT.file_name())
    seconds = [i["seconds"] for i in report["images"]]
    ctx.progress(
        1.0, f"{len(seconds)} depth maps, {1000 * sum(seconds) / len(seconds):.0f} ms a frame"
    )
    return {
        "images": len(seconds),
        "mean_seconds": round(sum(seconds) / len(seconds), 4),
        "int8": ctx.params.int8,
    }
