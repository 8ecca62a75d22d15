"""Training vista's teacher: Monodepth2's depth network (``nets.Teacher``) on drive folders,

- ``stereo``: self-supervised from the right camera (known baseline: metric depth);
- ``mono``: self-supervised from the previous and next frames, their poses from
  ``nets.PoseNet`` (depth up to scale: evaluate with median scaling);
- ``both``: the right camera and the neighbouring frames together (Monodepth2's MS);
- ``depth``: supervised by the drives' depth maps (L1 of log depth and the scale-invariant
  gradient loss), where ground truth exists (simulated drives, depth benchmark folders);
- ``lidar``: supervised the same way by the drives' own LiDAR scans (``velodyne/`` and the
  calibration, projected at the training size: ``lidar.py``); a drive without scans gives
  its depth maps, so simulated drives can be mixed in.

Any of them can start from a trained teacher (``initial``: an ONNX file of vista's, its batch
norms folded into the convolutions) to adapt a simulator-trained model to the user's camera;
then only the full-resolution disparity is trained (the export keeps no other head).

Self-supervision follows Monodepth2: at four scales, disparity upsampled to the input size,
the per-pixel minimum reprojection error over sources with auto-masking, plus edge-aware
smoothness weighted 1e-3 / 2^scale.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import get_args

import numpy as np

from services.depth.data import FrameSet
from services.depth.kinds import Supervision
from services.depth.training import (
    Batch,
    DepthTrainConfig,
    FitResult,
    Progress,
    fingerprint,
    fit,
    make_batch,
)

SUPERVISIONS: tuple[Supervision, ...] = get_args(Supervision)
SUPERVISED: tuple[Supervision, ...] = ("depth", "lidar")
TRAINING_HEADS = ("heads.1", "heads.2", "heads.3")
"""The coarser disparities' heads: trained, but not in an exported teacher."""
TEACHER_ARCHITECTURE = "monodepth2-resnet18"
SMOOTHNESS = 1e-3
GRADIENT_WEIGHT = 0.5
TRUTH_RANGE_M = (0.1, 80.0)


@dataclass
class TeacherResult:
    model: object
    """The trained ``nets.Teacher`` (eval mode)."""
    fit: FitResult
    supervision: Supervision
    val_abs_rel: float | None
    """AbsRel on the validation drives when they have depth (median-scaled for ``mono``)."""
    split: dict[str, int]


def axis_angle_matrix(pose):  # noqa: ANN001, ANN201 - torch tensors
    """(N, 6) axis-angle rotation and translation → (N, 4, 4) transforms (Rodrigues)."""
    import torch

    rotation, translation = pose[:, :3], pose[:, 3:]
    angle = rotation.norm(dim=1, keepdim=True).clamp(min=1e-8)
    axis = rotation / angle
    x, y, z = axis[:, 0], axis[:, 1], axis[:, 2]
    zero = torch.zeros_like(x)
    cross = torch.stack((zero, -z, y, z, zero, -x, -y, x, zero), dim=1).reshape(-1, 3, 3)
    eye = torch.eye(3, device=pose.device).expand_as(cross)
    sin, cos = angle.sin()[..., None], angle.cos()[..., None]
    R = eye + sin * cross + (1 - cos) * (cross @ cross)
    out = torch.eye(4, device=pose.device).repeat(len(pose), 1, 1)
    out[:, :3, :3] = R
    out[:, :3, 3] = translation
    return out


def supervision_needs(frames: FrameSet, supervision: Supervision) -> None:
    """ValueError naming what the frames lack for ``supervision``."""
    if supervision not in SUPERVISIONS:
        raise ValueError(f"supervision {supervision!r}: one of {', '.join(SUPERVISIONS)}")
    if supervision in ("stereo", "both") and frames.right is None:
        raise ValueError(
            f"--supervision {supervision} needs every drive's right camera (image_03/)"
        )
    if supervision in ("mono", "both") and not (frames.previous >= 0).any():
        raise ValueError(
            f"--supervision {supervision} needs drives of three or more consecutive frames"
        )
    if supervision == "depth" and frames.depth_m is None:
        raise ValueError(
            "--supervision depth needs a depth map for every frame (depth/ or proj_depth/)"
        )
    if supervision == "lidar" and frames.depth_m is None:
        raise ValueError(
            "--supervision lidar needs every drive's scans (velodyne/*.bin named as its "
            "images, and calib.json or calib_velo_to_cam.txt + calib_cam_to_cam.txt) or, "
            "for a simulated drive, its depth/"
        )


def scale_depths(out: dict, size: tuple[int, int], scales: int = 4) -> list:
    """The first ``scales`` scales' disparities upsampled to the input size, as depth
    (Monodepth2's practice)."""
    import torch.nn.functional as F

    from services.depth.nets import disparity_to_depth

    maps = [out["disparity"]] + [
        out[f"disparity_{s}"] for s in range(1, scales) if f"disparity_{s}" in out
    ]
    return [
        (
            disparity_to_depth(F.interpolate(d, size=size, mode="bilinear", align_corners=False))
            if d.shape[2:] != size
            else disparity_to_depth(d),
            d,
        )
        for d in maps
    ]


def self_supervised_loss(batch: Batch, depth_m, disparity, scale: int, sources: list) -> tuple:  # noqa: ANN001 - torch tensors
    """Monodepth2's loss at one scale: min reprojection with auto-masking over ``sources``
    ((image, source_T_target) pairs) plus smoothness; and the share of pixels kept."""
    import torch.nn.functional as F

    from services.depth.losses import reprojection_loss, smoothness, warp

    warped = [warp(image, depth_m, batch.K, source_T_target) for image, source_T_target in sources]
    photometric, kept = reprojection_loss(batch.image, warped, [image for image, _ in sources])
    small = F.interpolate(
        batch.image, size=disparity.shape[2:], mode="bilinear", align_corners=False
    )
    return photometric + SMOOTHNESS / 2**scale * smoothness(disparity, small), kept


def supervised_loss(depth_m, truth_m) -> object:  # noqa: ANN001 - torch tensors
    from services.depth.losses import gradient_matching, log_l1

    valid = (truth_m > TRUTH_RANGE_M[0]) & (truth_m < TRUTH_RANGE_M[1])
    return log_l1(depth_m, truth_m, valid) + GRADIENT_WEIGHT * gradient_matching(
        depth_m, truth_m, valid
    )


def abs_rel(
    predict: Callable, frames: FrameSet, index: np.ndarray, median_scaling: bool, batch: int = 16
) -> float:
    """Mean AbsRel over ``index``'s frames at the training size (1e-3–80 m, no crop)."""
    import torch

    from services.depth.metrics import evaluate_image

    scores = []
    for first in range(0, len(index), batch):
        chosen = index[first : first + batch]
        x = torch.from_numpy(frames.images[chosen]).float() / 255
        with torch.no_grad():
            depth = predict(x).numpy()[:, 0]
        for k, frame in enumerate(chosen):
            truth = frames.depth_m[frame, 0]
            if (truth > 0).any():
                scores.append(
                    evaluate_image(
                        truth, depth[k], crop="none", median_scaling=median_scaling
                    ).errors.abs_rel
                )
    return float(np.mean(scores)) if scores else float("nan")


def load_teacher(path: Path):  # noqa: ANN201 - a nets.Teacher
    """A teacher ONNX file of vista's as a ``nets.Teacher`` to train further (batch norms
    folded); ValueError when the file holds another network."""
    from services.depth.nets import Teacher
    from services.lib.nn.onnx_io import fold_batch_norms, load_onnx_weights, read_model

    architecture = read_model(path).metadata.get("architecture")
    if architecture != TEACHER_ARCHITECTURE:
        raise ValueError(
            f"{path}: a {architecture!r} model; fine-tuning starts from a teacher "
            f"({TEACHER_ARCHITECTURE}, written by vista depth train --network teacher)"
        )
    teacher = fold_batch_norms(Teacher())
    load_onnx_weights(teacher, path, unused=TRAINING_HEADS)
    return teacher


def train_teacher(
    frames: FrameSet,
    supervision: Supervision,
    config: DepthTrainConfig,
    *,
    initial: Path | None = None,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
) -> TeacherResult:
    """Train ``nets.Teacher`` on ``frames`` with ``supervision`` (module docstring), from
    scratch or from the teacher in ``initial``."""
    import torch

    from services.depth.data import split_by_group
    from services.depth.nets import PoseNet, Teacher

    supervision_needs(frames, supervision)
    torch.manual_seed(config.seed)
    teacher = load_teacher(initial) if initial is not None else Teacher()
    scales = 1 if initial is not None else 4
    modules = {"depth": teacher}
    if supervision in ("mono", "both"):
        modules["pose"] = PoseNet()
    train_index, val_index = split_by_group(
        frames, config.val_fraction, config.seed, config.val_groups
    )
    if supervision in ("mono", "both"):
        has_neighbours = (frames.previous >= 0) & (frames.following >= 0)
        train_index = train_index[has_neighbours[train_index]]
    if len(train_index) < config.batch:
        raise ValueError(
            f"{len(train_index)} training frames for batches of {config.batch}: give more frames or a smaller --batch"
        )
    size = frames.images.shape[2:]

    def step(batch: Batch) -> tuple:
        out = teacher.forward_train(batch.network_input)
        total, kept = 0.0, []
        for scale, (depth_m, disparity) in enumerate(scale_depths(out, size, scales)):
            if supervision in SUPERVISED:
                total = total + supervised_loss(depth_m, batch.depth_m)
                continue
            sources = []
            if supervision in ("stereo", "both"):
                sources.append((batch.right, batch.right_T_cam))
            if supervision in ("mono", "both"):
                previous_T_cam = axis_angle_matrix(
                    modules["pose"](batch.network_input, batch.previous)
                )
                following_T_cam = axis_angle_matrix(
                    modules["pose"](batch.network_input, batch.following)
                )
                sources += [(batch.previous, previous_T_cam), (batch.following, following_T_cam)]
            loss, share = self_supervised_loss(batch, depth_m, disparity, scale, sources)
            total, kept = total + loss, [*kept, float(share)]
        logs = {"automask_kept": float(np.mean(kept))} if kept else {}
        return total / scales, logs

    has_truth = frames.depth_m is not None
    median = supervision == "mono"
    if supervision in ("mono", "both"):
        val_index = val_index[((frames.previous >= 0) & (frames.following >= 0))[val_index]]

    def validate() -> float:
        if has_truth:
            return abs_rel(teacher, frames, val_index, median)
        batches = (val_index[k : k + config.batch] for k in range(0, len(val_index), config.batch))
        return float(
            np.mean(
                [
                    float(step(make_batch(frames, b, np.random.default_rng(0), False, "cpu"))[0])
                    for b in batches
                ]
            )
        )

    start = hashlib.sha256(Path(initial).read_bytes()).hexdigest() if initial else None
    run = fingerprint(config, frames, {"teacher": supervision, "initial": start})
    result = fit(
        modules,
        step,
        validate,
        frames,
        train_index,
        config,
        run=run,
        checkpoint_dir=checkpoint_dir,
        progress=progress,
    )
    score = abs_rel(teacher, frames, val_index, median) if has_truth else None
    return TeacherResult(
        teacher, result, supervision, score, {"train": len(train_index), "val": len(val_index)}
    )


def save_teacher(
    result: TeacherResult,
    path: Path,
    config: DepthTrainConfig,
    *,
    width: int,
    height: int,
    **extra: object,
) -> dict:
    """Export the teacher as ONNX with its features and its training in the metadata;
    returns the metrics written."""
    from services.depth.export import export_depth_model
    from services.depth.training import training_record

    training = training_record(
        result.fit, config, result.split, supervision=result.supervision, **extra
    )
    metrics = (
        {"val_abs_rel": result.val_abs_rel}
        if result.val_abs_rel is not None
        else {"val_loss": result.fit.best_score}
    )
    export_depth_model(
        result.model,
        path,
        width=width,
        height=height,
        architecture=TEACHER_ARCHITECTURE,
        features=True,
        extra={"training": training, "metrics": metrics},
    )
    return metrics
