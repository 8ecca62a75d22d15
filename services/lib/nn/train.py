"""A seeded training loop with progress and checkpoints, for any regression network:
SGD with momentum on the mean squared error, gradients clipped, a cosine schedule.

The targets' columns may differ in unit and size (millimetres and degrees): the network
learns them standardised — each column's training mean and spread are a fixed last layer
of the model it returns (``Rescaled``), so that model answers in the targets' own units and
the loss weighs every column alike.

The data are numpy arrays (inputs, targets); a seeded split keeps ``val_fraction`` aside to
choose the weights by and ``test_fraction`` that nothing is chosen by (the thesis's 80/10/10),
and the result gives both sets' RMSE per target column.
Each epoch's checkpoint (weights, optimiser, epoch, history) is written to
``checkpoint_dir``; a run started again with the same directory resumes after the last
finished epoch. The weights kept are the best on the validation set.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import asdict, dataclass, field, replace
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


def _fingerprint(config: TrainConfig, inputs: np.ndarray, targets: np.ndarray) -> dict:
    """What makes a checkpoint this run's: the settings that shape training and the data
    (more epochs may follow a finished run: the schedule stretches to them)."""
    ignored = ("device", "threads", "epochs")
    settings = {k: v for k, v in asdict(config).items() if k not in ignored}
    data = hashlib.sha256(np.ascontiguousarray(targets).tobytes())
    data.update(str(inputs.shape).encode())
    return {"settings": settings, "data": data.hexdigest()}


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

    from services.lib.nn.checkpoint import load_checkpoint, save_checkpoint
    from services.lib.nn.device import choose_device, torch_threads

    with torch_threads(config.threads):
        say = progress or (lambda fraction, message: None)
        if len(inputs) != len(targets) or len(inputs) < 2:
            raise ValueError(f"{len(inputs)} inputs and {len(targets)} targets: need ≥ 2 pairs")
        torch.manual_seed(config.seed)
        device = choose_device(config.device)
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
        # images (N, C, H, W) train about a fifth faster with their channels last on the CPU
        layout = torch.channels_last if x.ndim == 4 else torch.contiguous_format
        model.to(device, memory_format=layout)
        weight = (1.0 / scale**2).to(device)
        optimiser = torch.optim.SGD(
            model.parameters(),
            lr=config.learning_rate,
            momentum=config.momentum,
            weight_decay=config.weight_decay,
        )
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=config.epochs)
        result = TrainResult(model, 0, -1, float("inf"))
        best_state = None
        start_epoch = 0
        run = _fingerprint(config, inputs, targets)
        saved = load_checkpoint(checkpoint_dir, run, say)
        if saved is not None:
            model.load_state_dict(saved["model"])
            optimiser.load_state_dict(saved["optimiser"])
            schedule.load_state_dict(saved["schedule"])
            schedule.T_max = config.epochs
            start_epoch = saved["epoch"] + 1
            result = replace(saved["result"], model=model)
            best_state = saved["best_state"]
            say(start_epoch / config.epochs, f"resuming after epoch {start_epoch}")
        started, earlier_s = time.perf_counter(), result.seconds
        for epoch in range(start_epoch, config.epochs):
            model.train()
            order = train_idx[
                np.random.default_rng([config.seed + 1, epoch]).permutation(len(train_idx))
            ]
            total = 0.0
            for first in range(0, len(order), config.batch):
                batch = torch.from_numpy(order[first : first + config.batch])
                xb, yb = x[batch].to(device, memory_format=layout), y[batch].to(device)
                optimiser.zero_grad()
                loss = ((model(xb) - yb).pow(2) * weight).mean()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), config.clip_norm)
                optimiser.step()
                total += float(loss.detach()) * len(batch)
            schedule.step()
            train_loss = total / len(order)
            if not np.isfinite(train_loss):
                raise ValueError(
                    f"training diverged in epoch {epoch + 1} (loss {train_loss}): lower the "
                    f"learning rate (now {config.learning_rate})"
                )
            val_loss = evaluate_loss(model, x[val_idx], y[val_idx], config.batch, device, weight)
            result.history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss})
            if val_loss < result.best_val_loss:
                result.best_val_loss, result.best_epoch = val_loss, epoch
                best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
            result.epochs_run = epoch + 1
            result.seconds = earlier_s + time.perf_counter() - started
            per_epoch_s = (time.perf_counter() - started) / (epoch + 1 - start_epoch)
            left_min = per_epoch_s * (config.epochs - epoch - 1) / 60
            say(
                (epoch + 1) / config.epochs,
                f"epoch {epoch + 1}/{config.epochs}: train {train_loss:.5f}, val {val_loss:.5f} "
                f"({per_epoch_s:.0f} s an epoch, about {left_min:.0f} min left)",
            )
            if checkpoint_dir is not None:
                save_checkpoint(
                    checkpoint_dir,
                    {
                        "run": run,
                        "model": model.state_dict(),
                        "optimiser": optimiser.state_dict(),
                        "schedule": schedule.state_dict(),
                        "epoch": epoch,
                        "result": replace(result, model=None),
                        "best_state": best_state,
                    },
                )
        if best_state is not None:
            model.load_state_dict(best_state)
        result.val_rmse = column_rmse(model, x[val_idx], y[val_idx], config.batch, device)
        if len(test_idx):
            result.test_rmse = column_rmse(model, x[test_idx], y[test_idx], config.batch, device)
        result.split = {"train": len(train_idx), "val": len(val_idx), "test": len(test_idx)}
        model.to("cpu", memory_format=torch.contiguous_format).eval()
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
