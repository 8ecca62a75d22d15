"""The one training loop of every learned service (depth, tracking, odometry's OE-Net by
``services.lib.nn.regression``): a seeded optimiser (Adam unless the caller builds another)
on a cosine schedule over the steps, gradients clipped, validation after every epoch
choosing the weights kept, checkpoints written atomically after every epoch and resumed
only by the same run (its fingerprint ``run``), progress with the time left.

A *batches* function makes a step's batch from sample indices (in a reader thread, the
next batch while the current one trains); a *step* function turns it
into a loss and a few logged numbers; a *validate* function scores the current weights
(lower is better).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from contract.vocabulary import Progress


class FitSettings(Protocol):
    epochs: int
    batch: int
    learning_rate: float
    seed: int
    threads: int
    device: str


@dataclass
class FitResult:
    best_epoch: int
    best_score: float
    history: list[dict]
    seconds: float


def fit(
    modules: dict,
    step: Callable[[object], tuple[object, dict]],
    validate: Callable[[], float],
    train_index: np.ndarray,
    batches: Callable[[np.ndarray, np.random.Generator, object], object],
    config: FitSettings,
    *,
    run: str,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
    channels_last: bool = True,
    keep_best: bool = True,
    make_optimiser: Callable[[list], object] | None = None,
    clip_norm: float = 10.0,
) -> FitResult:
    """Train every module of ``modules`` (name → torch module) by Adam on a cosine schedule
    on ``step``'s loss over the samples ``train_index`` for ``config.epochs`` (each step's
    batch made by ``batches(indices, rng, device)``); keep the weights ``validate`` scores
    lowest (it runs after every epoch, modules in eval mode, without gradients) — or, with
    ``keep_best`` off, the last epoch's (when the validation data must stay unseen by every
    choice, as a user's held-out scans). ``channels_last``: image networks train about a
    fifth faster so on the CPU. ``make_optimiser`` builds the optimiser from the parameters
    (default: Adam at ``config.learning_rate``); gradients are clipped to ``clip_norm``."""
    import torch

    from services.lib.nn.checkpoint import load_checkpoint, save_checkpoint
    from services.lib.nn.device import choose_device, torch_threads

    with torch_threads(config.threads):
        say = progress or (lambda fraction, message: None)
        device = choose_device(config.device)
        layout = torch.channels_last if channels_last else torch.contiguous_format
        for module in modules.values():
            module.to(device, memory_format=layout)
        parameters = [p for m in modules.values() for p in m.parameters()]
        if make_optimiser is None:
            optimiser = torch.optim.Adam(parameters, lr=config.learning_rate)
        else:
            optimiser = make_optimiser(parameters)
        steps_per_epoch = max(1, len(train_index) // config.batch)
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(
            optimiser, T_max=config.epochs * steps_per_epoch
        )
        result = FitResult(-1, float("inf"), [], 0.0)
        best_state = None
        start_epoch = 0
        saved = load_checkpoint(checkpoint_dir, run, say)
        if saved is not None:
            for name, module in modules.items():
                module.load_state_dict(saved["modules"][name])
            optimiser.load_state_dict(saved["optimiser"])
            schedule.load_state_dict(saved["schedule"])
            schedule.T_max = config.epochs * steps_per_epoch
            start_epoch, result, best_state = (
                saved["epoch"] + 1,
                saved["result"],
                saved["best_state"],
            )
            say(start_epoch / config.epochs, f"resuming after epoch {start_epoch}")
        started, earlier_s = time.perf_counter(), result.seconds
        reader = ThreadPoolExecutor(1, thread_name_prefix="batches")
        try:
            for epoch in range(start_epoch, config.epochs):
                for module in modules.values():
                    module.train()
                rng = np.random.default_rng([config.seed, 31, epoch])
                order = rng.permutation(train_index)
                totals: dict[str, float] = {}

                def make(
                    k: int, order: np.ndarray = order, rng: np.random.Generator = rng
                ) -> object:
                    return batches(order[k * config.batch : (k + 1) * config.batch], rng, device)

                # the next batch is made while this one trains (one reader thread, in order, so the
                # batches and their random draws are those of a serial run)
                upcoming = reader.submit(make, 0)
                for k in range(steps_per_epoch):
                    batch = upcoming.result()
                    if k + 1 < steps_per_epoch:
                        upcoming = reader.submit(make, k + 1)
                    loss, logs = step(batch)
                    optimiser.zero_grad()
                    loss.backward()
                    torch.nn.utils.clip_grad_norm_(parameters, clip_norm)
                    optimiser.step()
                    schedule.step()
                    value = float(loss.detach())
                    if not np.isfinite(value):
                        raise ValueError(
                            f"training diverged in epoch {epoch + 1}: lower the learning rate (now {config.learning_rate})"
                        )
                    for key, number in {"loss": value, **logs}.items():
                        totals[key] = totals.get(key, 0.0) + float(number) / steps_per_epoch
                    if k % 20 == 0:
                        say(
                            (epoch + (k + 1) / steps_per_epoch) / config.epochs,
                            f"epoch {epoch + 1}/{config.epochs}, step {k + 1}/{steps_per_epoch}: loss {value:.4f}",
                        )
                for module in modules.values():
                    module.eval()
                with torch.no_grad():
                    score = float(validate())
                result.history.append(
                    {
                        "epoch": epoch + 1,
                        **{k: round(v, 6) for k, v in totals.items()},
                        "val": score,
                    }
                )
                if score < result.best_score or (not keep_best and epoch + 1 == config.epochs):
                    result.best_score, result.best_epoch = score, epoch + 1
                    best_state = {
                        n: {k: v.detach().clone() for k, v in m.state_dict().items()}
                        for n, m in modules.items()
                    }
                result.seconds = earlier_s + time.perf_counter() - started
                per_epoch_s = (time.perf_counter() - started) / (epoch + 1 - start_epoch)
                say(
                    (epoch + 1) / config.epochs,
                    f"epoch {epoch + 1}/{config.epochs}: loss {totals.get('loss', float('nan')):.4f}, "
                    f"validation {score:.4f} ({per_epoch_s:.0f} s an epoch, about "
                    f"{per_epoch_s * (config.epochs - epoch - 1) / 60:.0f} min left)",
                )
                if checkpoint_dir is not None:
                    save_checkpoint(
                        checkpoint_dir,
                        {
                            "run": run,
                            "modules": {n: m.state_dict() for n, m in modules.items()},
                            "optimiser": optimiser.state_dict(),
                            "schedule": schedule.state_dict(),
                            "epoch": epoch,
                            "result": result,
                            "best_state": best_state,
                        },
                    )
        finally:
            reader.shutdown(cancel_futures=True)
        if best_state is not None:
            for name, module in modules.items():
                module.load_state_dict(best_state[name])
        for module in modules.values():
            module.to("cpu", memory_format=torch.contiguous_format).eval()
        return result
