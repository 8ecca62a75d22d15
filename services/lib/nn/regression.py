"""Training a regression network (OE-Net) by the shared loop (``services.lib.nn.fit``):
SGD with momentum on the mean squared error, gradients clipped, a cosine schedule.

The targets' columns may differ in unit and size (millimetres and degrees): the network
learns them standardised — each column's training mean and spread are a fixed last layer
of the model it returns (``Rescaled``), so that model answers in the targets' own units and
the loss weighs every column alike.

The data are numpy arrays (inputs, targets); a seeded split keeps ``val_fraction`` aside to
choose the weights by and ``test_fraction`` that nothing is chosen by (the thesis's 80/10/10),
and the result gives both sets' RMSE per target column. Checkpoints and resuming are the
loop's: a run started again with the same ``checkpoint_dir`` resumes after the last
finished epoch. The weights kept are the best on the validation set.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from contract.vocabulary import Progress


@dataclass(frozen=True)
class TrainConfig:
    epochs: int = 30
    batch: int = 256
    learning_rate: float = 0.01
    momentum: float = 0.9
    weight_decay: float = 1e-4
    clip_norm: float = 5.0
    """Gradients are scaled down to at most this norm (large targets, early steps)."""
    val_fraction: float = 0.1
    test_fraction: float = 0.1
    seed: int = 0
    device: str = "auto"
    threads: int = 2
    standardize_targets: bool = True


@dataclass
class TrainResult:
    model: object
    """The trained network (in ``Rescaled`` when the targets were standardised): the one
    to export."""
    epochs_run: int
    best_epoch: int
    """Counted from 1."""
    best_val_loss: float
    history: list[dict] = field(default_factory=list)
    seconds: float = 0.0
    """Training time over every run that made this result (a resumed one included)."""
    val_rmse: list[float] = field(default_factory=list)
    """Per target column, with the best weights."""
    test_rmse: list[float] | None = None
    """Per target column on the pairs kept out of training and of the choice of weights
    (None: no test set)."""
    split: dict[str, int] = field(default_factory=dict)
    """How many samples trained, validated and tested."""


def _fingerprint(config: TrainConfig, inputs: np.ndarray, targets: np.ndarray) -> str:
    """What makes a checkpoint this run's: the settings that shape training and the data
    (more epochs may follow a finished run: the schedule stretches to them)."""
    ignored = ("device", "threads", "epochs")
    settings = {k: v for k, v in asdict(config).items() if k not in ignored}
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode())
    digest.update(np.ascontiguousarray(targets).tobytes())
    digest.update(str(inputs.shape).encode())
    return digest.hexdigest()


def split(
    count: int, val_fraction: float, test_fraction: float, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeded indices for training, validation (at least one) and test."""
    order = np.random.default_rng(seed).permutation(count)
    val = max(1, int(round(count * val_fraction))) if count > 1 else 0
    test = int(round(count * test_fraction)) if count > 2 else 0
    return order[val + test :], order[:val], order[val : val + test]


def rescaled(model, mean: np.ndarray, std: np.ndarray):  # noqa: ANN001, ANN201 - torch modules
    """``model`` whose outputs are scaled by ``std`` and shifted by ``mean`` (per column)."""
    import torch

    class Rescaled(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.inner = model
            self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
            self.register_buffer("std", torch.as_tensor(std, dtype=torch.float32))

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return self.inner(x) * self.std + self.mean

    return Rescaled()


def train(
    model,  # noqa: ANN001 - a torch.nn.Module
    inputs: np.ndarray,
    targets: np.ndarray,
    config: TrainConfig,
    *,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
) -> TrainResult:
    """Train ``model`` by SGD with momentum on the mean squared error (of the standardised
    targets when ``config.standardize_targets``). The result's ``model`` — ``model`` itself,
    or ``model`` inside ``Rescaled`` — ends with the best validation weights and answers in
    the targets' units: export that one (``model`` alone then answers standardised)."""
    import torch

    from services.lib.nn.fit import fit

    if len(inputs) != len(targets) or len(inputs) < 2:
        raise ValueError(f"{len(inputs)} inputs and {len(targets)} targets: need ≥ 2 pairs")
    torch.manual_seed(config.seed)
    train_idx, val_idx, test_idx = split(
        len(inputs), config.val_fraction, config.test_fraction, config.seed
    )
    x = torch.from_numpy(np.ascontiguousarray(inputs, dtype=np.float32))
    y = torch.from_numpy(np.ascontiguousarray(targets, dtype=np.float32))
    scale = torch.ones(y.shape[1])
    if config.standardize_targets:
        mean, std = targets[train_idx].mean(axis=0), targets[train_idx].std(axis=0)
        std = np.where(std > 1e-12, std, 1.0)
        model = rescaled(model, mean, std)
        scale = torch.as_tensor(std, dtype=torch.float32)
    weight = 1.0 / scale**2
    # images (N, C, H, W) train about a fifth faster with their channels last on the CPU
    images = x.ndim == 4
    layout = torch.channels_last if images else torch.contiguous_format

    def device() -> torch.device:
        return next(model.parameters()).device

    def batches(index: np.ndarray, rng: np.random.Generator, on: torch.device) -> tuple:
        rows = torch.from_numpy(index)
        return x[rows].to(on, memory_format=layout), y[rows].to(on)

    def step(batch: tuple) -> tuple[torch.Tensor, dict]:
        xb, yb = batch
        return ((model(xb) - yb).pow(2) * weight.to(yb.device)).mean(), {}

    def validate() -> float:
        return evaluate_loss(model, x[val_idx], y[val_idx], config.batch, device(), weight)

    fitted = fit(
        {"model": model}, step, validate, train_idx, batches, config,
        run=_fingerprint(config, inputs, targets), checkpoint_dir=checkpoint_dir,
        progress=progress, channels_last=images, clip_norm=config.clip_norm,
        make_optimiser=lambda parameters: torch.optim.SGD(
            parameters, lr=config.learning_rate, momentum=config.momentum,
            weight_decay=config.weight_decay,
        ),
    )  # fmt: skip
    result = TrainResult(
        model,
        epochs_run=len(fitted.history),
        best_epoch=fitted.best_epoch,
        best_val_loss=fitted.best_score,
        history=fitted.history,
        seconds=fitted.seconds,
        val_rmse=column_rmse(model, x[val_idx], y[val_idx], config.batch, "cpu"),
        split={"train": len(train_idx), "val": len(val_idx), "test": len(test_idx)},
    )
    if len(test_idx):
        result.test_rmse = column_rmse(model, x[test_idx], y[test_idx], config.batch, "cpu")
    return result


def predict(model, x, batch: int, device):  # noqa: ANN001, ANN201 - torch objects
    """``model``'s outputs for ``x`` in batches, on the CPU."""
    import torch

    model.eval()
    with torch.no_grad():
        return torch.cat(
            [model(x[k : k + batch].to(device)).cpu() for k in range(0, len(x), batch)]
        )


def column_rmse(model, x, y, batch: int, device) -> list[float]:  # noqa: ANN001 - torch objects
    """Root mean squared error of each output column of ``model`` on (x, y)."""
    error = predict(model, x, batch, device) - y
    return [float(v) for v in error.pow(2).mean(dim=0).sqrt()]


def evaluate_loss(model, x, y, batch: int, device, weight) -> float:  # noqa: ANN001 - torch objects
    """Mean squared error of ``model`` on (x, y), each column weighted by ``weight``; nan
    without samples."""
    if len(x) == 0:
        return float("nan")
    return float(((predict(model, x, batch, device) - y).pow(2) * weight.cpu()).mean())
