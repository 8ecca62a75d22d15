"""Training checkpoints: one file per run directory, written atomically, resumed only by the
run that wrote it (its fingerprint: the data and the settings that shape training)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

CHECKPOINT = "last.pt"


def save_checkpoint(directory: Path, state: dict) -> None:
    """Write ``state`` (with its ``run`` fingerprint) so that a kill mid-write leaves the
    previous checkpoint."""
    import torch

    directory.mkdir(parents=True, exist_ok=True)
    partial = directory / (CHECKPOINT + ".partial")
    torch.save(state, partial)
    os.replace(partial, directory / CHECKPOINT)


def load_checkpoint(
    directory: Path | None, run: object, say: Callable[[float, str], None]
) -> dict | None:
    """The checkpoint in ``directory`` when it is ``run``'s; None (saying why) otherwise."""
    import torch

    path = directory / CHECKPOINT if directory else None
    if path is None or not path.exists():
        return None
    saved = torch.load(path, map_location="cpu", weights_only=False)
    if saved.get("run") != run:
        say(0.0, f"{path} is another run's checkpoint (other data or settings): starting afresh")
        return None
    return saved
