"""The depth networks' training: seeded batches with Monodepth2's augmentation through the
shared loop (``services.lib.nn.fit``: Adam on a cosine schedule, validation after every epoch
choosing the weights kept, checkpoints resumed only by the same run, progress).

A *step* function turns a ``Batch`` into a loss and a few logged numbers; a *validate*
function scores the current weights (lower is better). The teacher's and the student's
training differ only in those two functions.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from contract.vocabulary import DeviceChoice
from services.depth.data import FrameSet
from services.depth.kinds import TRAIN
from services.lib.nn.fit import FitResult, Progress
from services.lib.nn.fit import fit as shared_fit

if TYPE_CHECKING:
    import torch


@dataclass(frozen=True)
class DepthTrainConfig:
    """A training's settings, its defaults ``depth.train``'s (``TrainParams``)."""

    epochs: int = TRAIN["epochs"].default
    batch: int = TRAIN["batch"].default
    learning_rate: float = TRAIN["learning_rate"].default
    seed: int = TRAIN["seed"].default
    threads: int = 2
    device: DeviceChoice = TRAIN["device"].default
    val_fraction: float = 0.1
    augment: bool = True
    """Random horizontal flips and colour jitter of the network's input (Monodepth2's)."""
    keep_best: bool = True
    """Keep the epoch validation scores best, or (off) the last: when the validation frames
    cannot speak for the frames that matter (adapting to real frames, validated on simulated
    ones)."""
    val_groups: tuple[int, ...] | None = None
    """Which folders (by their order) validate; None: a random ``val_fraction`` of them."""


@dataclass
class Batch:
    """Frames of one step as tensors (float 0–1 images)."""

    index: object
    """(B,) frame indices (torch long)."""
    flipped: object
    """(B,) bool: mirrored left–right."""
    image: object
    """(B, 3, H, W) what the losses compare (not colour-jittered)."""
    network_input: object
    """(B, 3, H, W) what the network sees (colour-jittered when augmenting)."""
    K: object
    right: object | None = None
    right_T_cam: object | None = None
    depth_m: object | None = None
    previous: object | None = None
    following: object | None = None
    previous_T_cam: object | None = None
    following_T_cam: object | None = None


def training_record(
    result: FitResult, config: DepthTrainConfig, split: dict[str, int], **extra: object
) -> dict:
    """What a model's metadata says of its training: ``extra`` (supervision, method, …),
    the epochs, the best, the frames, the time and each epoch's losses."""
    return {
        **extra,
        "epochs": config.epochs,
        "best_epoch": result.best_epoch,
        "frames": split,
        "seconds": round(result.seconds, 1),
        "history": result.history,
    }


MIRROR = np.diag([-1.0, 1.0, 1.0, 1.0]).astype(np.float32)


def make_batch(
    frames: FrameSet,
    index: np.ndarray,
    rng: np.random.Generator,
    augment: bool,
    device: torch.device,
) -> Batch:
    """The frames at ``index`` as a batch; when augmenting, each is mirrored with probability
    ½ (images, depth, intrinsics, stereo side and poses alike) and its network input gets
    random brightness, contrast and saturation (±20 %) and a hue-like channel gain (±5 %)."""
    import torch

    def tensor(array: np.ndarray, flip: np.ndarray) -> torch.Tensor:
        array = array.copy()
        array[flip] = array[flip][..., ::-1]
        out = torch.from_numpy(np.ascontiguousarray(array))
        return (out.float() / 255 if array.dtype == np.uint8 else out.float()).to(device)

    count = len(index)
    flip = rng.random(count) < 0.5 if augment else np.zeros(count, bool)
    width = frames.images.shape[3]
    K = frames.K[index].copy()
    K[flip, 0, 2] = width - 1 - K[flip, 0, 2]

    def mirrored(transforms: np.ndarray) -> np.ndarray:
        out = transforms.copy()
        out[flip] = MIRROR @ out[flip] @ MIRROR
        return out

    image = tensor(frames.images[index], flip)
    batch = Batch(
        index=torch.from_numpy(index),
        flipped=torch.from_numpy(flip),
        image=image,
        network_input=_jitter(image, rng) if augment else image,
        K=torch.from_numpy(K).to(device),
    )
    if frames.right is not None:
        batch.right = tensor(frames.right[index], flip)
        right_T_cam = np.tile(np.eye(4, dtype=np.float32), (count, 1, 1))
        # the right camera sits one baseline along +x; mirrored, it is on the left
        right_T_cam[:, 0, 3] = -frames.baseline_m[index] * np.where(flip, -1, 1)
        batch.right_T_cam = torch.from_numpy(right_T_cam).to(device)
    if frames.depth_m is not None:
        batch.depth_m = tensor(frames.depth_m[index], flip)
    previous, following = frames.previous[index], frames.following[index]
    if (previous >= 0).all() and (following >= 0).all():
        batch.previous = tensor(frames.images[previous], flip)
        batch.following = tensor(frames.images[following], flip)
        batch.previous_T_cam = torch.from_numpy(mirrored(frames.previous_T_cam[index])).to(device)
        batch.following_T_cam = torch.from_numpy(mirrored(frames.following_T_cam[index])).to(device)
    return batch


def _jitter(image, rng: np.random.Generator):  # noqa: ANN001, ANN202 - torch tensors
    import torch

    count = image.shape[0]

    def draw(spread: float, shape: tuple[int, ...]) -> torch.Tensor:
        return torch.from_numpy(rng.uniform(1 - spread, 1 + spread, shape).astype(np.float32)).to(
            image.device
        )

    out = image * draw(0.2, (count, 1, 1, 1))
    mean = out.mean(dim=(1, 2, 3), keepdim=True)
    out = (out - mean) * draw(0.2, (count, 1, 1, 1)) + mean
    grey = out.mean(dim=1, keepdim=True)
    out = (out - grey) * draw(0.2, (count, 1, 1, 1)) + grey
    out = out * draw(0.05, (count, 3, 1, 1))
    return out.clamp(0, 1)


def fingerprint(config: DepthTrainConfig, frames: FrameSet, what: dict) -> str:
    """What makes a checkpoint this run's: the settings, the data and the run's own terms."""
    settings = {k: v for k, v in asdict(config).items() if k not in ("threads", "device", "epochs")}
    digest = hashlib.sha256(
        json.dumps({"settings": settings, "what": what}, sort_keys=True).encode()
    )
    digest.update(frames.images[:: max(1, len(frames) // 64)].tobytes())
    digest.update(str(frames.images.shape).encode())
    return digest.hexdigest()


def fit(
    modules: dict,
    step: Callable[[Batch], tuple[object, dict]],
    validate: Callable[[], float],
    frames: FrameSet,
    train_index: np.ndarray,
    config: DepthTrainConfig,
    *,
    run: str,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
) -> FitResult:
    """The shared loop (``services.lib.nn.fit``) over batches of ``frames`` with Monodepth2's
    augmentation, the network's input channels last."""
    import torch

    def batches(index: np.ndarray, rng: np.random.Generator, device: torch.device) -> Batch:
        batch = make_batch(frames, index, rng, config.augment, device)
        batch.network_input = batch.network_input.contiguous(memory_format=torch.channels_last)
        return batch

    return shared_fit(
        modules, step, validate, train_index, batches, config,
        run=run, checkpoint_dir=checkpoint_dir, progress=progress, keep_best=config.keep_best,
    )  # fmt: skip
