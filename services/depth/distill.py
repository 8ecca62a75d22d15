"""Distilling a teacher (any ONNX depth model, ``models.DepthModel``) into the student
(``nets.Student``, DeepLabv3+ with MobileNetV2).

- ``thesis`` (5.2.2): the L1 difference of the student's and the teacher's depth maps.
- ``vista``: the teacher's depth in log space (L1) and its edges by the scale-invariant
  gradient loss, hints from the teacher's intermediate features when its file has them
  (``encoder``, ``decoder`` outputs; a learned 1 × 1 adapter per hint), and the photometric
  loss of the student's own depth where the frames allow it (a right camera, or neighbouring
  frames with known poses) — the thesis's future work.

The teacher's answers for every frame (and its mirror image, for the flip augmentation) are
computed once before training, at the student's size.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, get_args

import numpy as np

from services.depth.data import FrameSet
from services.depth.kinds import DistillMethod
from services.depth.models import DepthModel
from services.depth.training import Batch, DepthTrainConfig, FitResult, Progress, fingerprint, fit

if TYPE_CHECKING:
    import torch

METHODS: tuple[DistillMethod, ...] = get_args(DistillMethod)
HINT_WEIGHT = 0.5
GRADIENT_WEIGHT = 0.5
PHOTOMETRIC_WEIGHT = 0.5
TEACHER_RANGE_M = (0.1, 80.0)
"""Where the teacher's depth is trusted by vista's log and gradient terms."""


@dataclass(frozen=True)
class TeacherTargets:
    depth_m: np.ndarray
    """(N, 2, H, W) float32: the teacher's depth for each frame and its mirror image, at the
    student's training size."""
    features: dict[str, np.ndarray]
    """name → (N, 2, C, h, w) float16, the teacher's own feature sizes."""


@dataclass
class StudentResult:
    model: object
    """The trained ``nets.Student`` (eval mode)."""
    fit: FitResult
    method: DistillMethod
    val_abs_rel_to_teacher: float
    hints: tuple[str, ...]
    photometric: str
    """What vista's photometric term used: ``stereo``, ``video`` or ``none``."""
    split: dict[str, int]


def teacher_targets(
    teacher: DepthModel, frames: FrameSet, *, features: bool, progress: Progress | None = None
) -> TeacherTargets:
    """Run ``teacher`` on every frame and its mirror image (resized to the teacher's input,
    its depth resized back to the frames' size)."""
    import cv2

    say = progress or (lambda fraction, message: None)
    height, width = frames.images.shape[2:]
    spec = teacher.spec
    depth = np.zeros((len(frames), 2, height, width), np.float32)
    maps: dict[str, np.ndarray] = {}
    batch = 8
    for first in range(0, len(frames), batch):
        chosen = frames.images[first : first + batch].transpose(0, 2, 3, 1)
        for mirrored in (0, 1):
            images = chosen[:, :, ::-1] if mirrored else chosen
            resized = np.stack(
                [
                    cv2.resize(
                        np.ascontiguousarray(im),
                        (spec.width, spec.height),
                        interpolation=cv2.INTER_AREA,
                    )
                    for im in images
                ]
            )
            answer = teacher.predict(resized, features=features)
            for k, d in enumerate(answer.depth_m):
                depth[first + k, mirrored] = cv2.resize(
                    d, (width, height), interpolation=cv2.INTER_LINEAR
                )
            for name, values in answer.features.items():
                if name not in maps:
                    maps[name] = np.zeros((len(frames), 2, *values.shape[1:]), np.float16)
                maps[name][first : first + len(values), mirrored] = values
        say(
            min(1.0, (first + batch) / len(frames)),
            f"teacher on {min(first + batch, len(frames))}/{len(frames)} frames",
        )
    return TeacherTargets(depth, maps)


def _pick(array: np.ndarray, batch: Batch, device: torch.device) -> torch.Tensor:
    import torch

    index, flipped = batch.index.numpy(), batch.flipped.numpy().astype(int)
    return torch.from_numpy(array[index, flipped].astype(np.float32)).to(device)


def distill(
    teacher: DepthModel,
    frames: FrameSet,
    method: DistillMethod,
    config: DepthTrainConfig,
    *,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
    targets: TeacherTargets | None = None,
) -> StudentResult:
    """Train ``nets.Student`` on ``frames`` from ``teacher`` by ``method`` (module docstring);
    ``targets`` reuses the teacher's answers already computed for these frames."""
    import torch
    from torch import nn

    from services.depth.data import split_by_group
    from services.depth.losses import feature_hint, gradient_matching, log_l1
    from services.depth.nets import Student
    from services.depth.teacher import self_supervised_loss

    if method not in METHODS:
        raise ValueError(f"method {method!r}: one of {', '.join(METHODS)}")
    say = progress or (lambda fraction, message: None)
    vista = method == "vista"
    if targets is None:
        targets = teacher_targets(
            teacher, frames, features=vista, progress=lambda f, m: say(0.0, m)
        )
    torch.manual_seed(config.seed)
    student = Student()
    modules: dict[str, nn.Module] = {"student": student}
    hints: tuple[str, ...] = ()
    if vista:
        channels = {
            "encoder": student.aspp.project[0].out_channels,
            "decoder": student.head.in_channels,
        }
        for name, values in targets.features.items():
            modules[f"adapter_{name}"] = nn.Conv2d(channels[name], values.shape[2], 1)
            hints += (name,)
    # the photometric term uses the right camera when every frame has one, else the
    # neighbouring frames when poses are known (then only frames with both neighbours train)
    stereo = frames.right is not None
    video = not stereo and bool(frames.has_poses.all() and (frames.previous >= 0).any())
    photometric = ("stereo" if stereo else "video" if video else "none") if vista else "none"
    train_index, val_index = split_by_group(
        frames, config.val_fraction, config.seed, config.val_groups
    )
    if video and vista:
        train_index = train_index[((frames.previous >= 0) & (frames.following >= 0))[train_index]]
    if len(train_index) < config.batch:
        raise ValueError(
            f"{len(train_index)} training frames for batches of {config.batch}: give more images or a smaller --batch"
        )

    def step(batch: Batch) -> tuple:
        out = student.forward_train(batch.network_input)
        goal = _pick(targets.depth_m, batch, out["depth"].device)[:, None]
        if not vista:
            return (out["depth"] - goal).abs().mean(), {}
        valid = (goal > TEACHER_RANGE_M[0]) & (goal < TEACHER_RANGE_M[1])
        terms = {
            "log_l1": log_l1(out["depth"], goal, valid),
            "gradient": GRADIENT_WEIGHT * gradient_matching(out["depth"], goal, valid),
        }
        for name in hints:
            teacher_map = _pick(targets.features[name], batch, goal.device)
            terms[f"hint_{name}"] = HINT_WEIGHT * feature_hint(
                out[name], teacher_map, modules[f"adapter_{name}"]
            )
        sources = []
        if stereo:
            sources.append((batch.right, batch.right_T_cam))
        if video:
            sources += [
                (batch.previous, batch.previous_T_cam),
                (batch.following, batch.following_T_cam),
            ]
        if sources:
            loss, _ = self_supervised_loss(batch, out["depth"], out["disparity"], 0, sources)
            terms["photometric"] = PHOTOMETRIC_WEIGHT * loss
        return sum(terms.values()), {k: float(v.detach()) for k, v in terms.items()}

    def validate() -> float:
        return agreement(student, frames, targets, val_index)

    run = fingerprint(
        config, frames, {"student": method, "teacher": str(teacher.path), "hints": list(hints)}
    )
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
    split = {"train": len(train_index), "val": len(val_index)}
    return StudentResult(
        student,
        result,
        method,
        agreement(student, frames, targets, val_index),
        hints,
        photometric,
        split,
    )


def agreement(
    student: Callable, frames: FrameSet, targets: TeacherTargets, index: np.ndarray, batch: int = 16
) -> float:
    """Mean AbsRel of the student's depth against the teacher's (0.1–80 m) over ``index``."""
    import torch

    scores = []
    for first in range(0, len(index), batch):
        chosen = index[first : first + batch]
        with torch.no_grad():
            depth = student(torch.from_numpy(frames.images[chosen]).float() / 255).numpy()[:, 0]
        goal = targets.depth_m[chosen, 0]
        valid = (goal > TEACHER_RANGE_M[0]) & (goal < TEACHER_RANGE_M[1])
        relative = np.abs(depth - goal) / np.where(valid, goal, 1)
        scores.append((relative * valid).sum(axis=(1, 2)) / np.maximum(valid.sum(axis=(1, 2)), 1))
    return float(np.concatenate(scores).mean()) if scores else float("nan")


STUDENT_ARCHITECTURE = "deeplabv3plus-mobilenetv2"


def save_student(
    result: StudentResult,
    path: Path,
    config: DepthTrainConfig,
    *,
    width: int,
    height: int,
    teacher: str,
    **extra: object,
) -> dict:
    """Export the student as ONNX with its training in the metadata; returns the metrics
    written."""
    from services.depth.export import export_depth_model
    from services.depth.training import training_record

    training = training_record(
        result.fit,
        config,
        result.split,
        method=result.method,
        teacher=teacher,
        hints=list(result.hints),
        photometric=result.photometric,
        **extra,
    )
    metrics = {"val_abs_rel_to_teacher": result.val_abs_rel_to_teacher}
    export_depth_model(
        result.model,
        path,
        width=width,
        height=height,
        architecture=STUDENT_ARCHITECTURE,
        extra={"training": training, "metrics": metrics},
    )
    return metrics
