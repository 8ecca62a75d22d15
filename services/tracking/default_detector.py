"""How vista's shipped car detector is built (``vista tracking build-default``), seeded,
from data this repository reproduces, as ``BuildSettings`` say:

1. ``drives`` simulated drives of ``frames`` frames (``vista tracking simulate``, seeds
   ``SIM_SEED`` …), kept in the work folder;
2. a detector trained on them alone (``vista tracking train``: the simulator-only model,
   kept for contrast);
3. that detector fine-tuned on KITTI's labelled object scans (``../shared/data/
   kitti-object-sample``) with cars pasted from them and from the simulated drives, and
   validated on a real drive it never saw (``../shared/data/kitti-raw-2011_09_26_drive_0048``,
   nothing chosen on it): the shipped model, whose metadata says so and carries KITTI's
   licence (CC BY-NC-SA 3.0). Its boxes are kept from ``THRESHOLD``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from pydantic import BaseModel, ConfigDict, Field

from services.lib.shared_data import SHARED_DATA
from services.tracking.kinds import FINE_TUNE_EPOCHS, FINE_TUNE_LEARNING_RATE, TrainParams

if TYPE_CHECKING:
    from services.tracking.detector_training import DetectorTrainConfig

REAL_TRAIN = SHARED_DATA / "kitti-object-sample"
REAL_HELD_OUT = SHARED_DATA / "kitti-raw-2011_09_26_drive_0048"
KITTI_LICENCE = (
    "trained on KITTI Vision Benchmark scans (Geiger, Lenz, Stiller, Urtasun; KIT and TTI), "
    "CC BY-NC-SA 3.0: non-commercial use, attribution, share alike"
)
SIM_DRIVES, SIM_FRAMES, SIM_SEED = 40, 60, 1000
THRESHOLD = 0.4
"""Chosen by re-running step 3 in three folds on the object scans (``bench_real``): recall
within 40 m and precision in view of the folds' held-out scans were 0.84 / 0.64 from 0.3,
0.80 / 0.74 from 0.4 and 0.76 / 0.80 from 0.5; 0.4 is the one that met both targets."""

Say = Callable[[str], None]


class BuildSettings(BaseModel):
    """What the shipped detector's build takes (``vista tracking build-default``'s options)."""

    model_config = ConfigDict(extra="forbid")

    drives: int = Field(
        SIM_DRIVES, ge=1, le=10_000, description="Simulated drives the first detector learns on."
    )
    frames: int = Field(SIM_FRAMES, ge=2, le=100_000, description="Frames a simulated drive.")
    tune_epochs: int = Field(
        FINE_TUNE_EPOCHS, ge=1, le=10_000, description="Passes of the fine-tuning on real scans."
    )
    tune_windows: int = Field(
        TrainParams.model_fields["windows"].default,
        ge=1,
        le=1_000_000,
        description="Training windows an epoch of the fine-tuning at least.",
    )
    seed: int = Field(
        0,
        ge=0,
        le=2**31 - 1,
        description=f"Random seed: initial weights, shuffling, pasting (the drives are seeds {SIM_SEED} on).",
    )

    def command(self) -> str:
        """The command that builds the model with these settings."""
        options = " ".join(
            f"--{name.replace('_', '-')} {value}" for name, value in self.model_dump().items()
        )
        return f"vista tracking build-default {options}"


def simulated_drives(
    folder: Path, count: int = SIM_DRIVES, frames: int = SIM_FRAMES, say: Say | None = None
) -> list[Path]:
    """The training drives (simulated where missing): ``folder/dSEED``."""
    from services.tracking.simulate import simulate_sequence

    drives = []
    for k in range(count):
        drive = folder / f"d{SIM_SEED + k}"
        if not (drive / "poses.txt").is_file():
            simulate_sequence(drive, frames=frames, cars=4 + k % 8, seed=SIM_SEED + k)
            if say:
                say(f"  simulated drive {k + 1}/{count}")
        drives.append(drive)
    return drives


def simulator_only(
    drives: list[Path], out: Path, config: DetectorTrainConfig, work: Path, say: Say
) -> Path:
    """The detector trained on simulated drives alone (kept: trained once)."""
    from services.tracking.detector_training import train_detector

    if not out.is_file():
        say(
            f"training the simulator-only detector on {len(drives)} drives ({config.epochs} epochs)"
        )
        train_detector(
            drives,
            out,
            config,
            checkpoint_dir=work / "checkpoints" / out.stem,
            progress=lambda fraction, message: say(f"  {message}"),
        )
    return out


def fine_tuned(
    base: Path,
    real: list[Path],
    out: Path,
    *,
    validate_on: list[Path] | None,
    paste_from: list[Path],
    seed: int,
    work: Path,
    say: Say,
    epochs: int = FINE_TUNE_EPOCHS,
    windows: int = TrainParams.model_fields["windows"].default,
    command: str,
) -> dict:
    """``base`` fine-tuned on the labelled scans of ``real`` (the metadata)."""
    from services.tracking.detector_training import DetectorTrainConfig, train_detector

    config = DetectorTrainConfig(
        epochs=epochs,
        learning_rate=FINE_TUNE_LEARNING_RATE,
        seed=seed,
        windows_per_epoch=windows,
        initial=str(base),
        threshold=THRESHOLD,
    )
    say(f"fine-tuning {base.name} on {', '.join(p.name for p in real)}")
    return train_detector(
        real,
        out,
        config,
        validate_on=validate_on,
        paste_from=paste_from,
        licence=KITTI_LICENCE,
        checkpoint_dir=work / "checkpoints" / out.stem,
        progress=lambda fraction, message: say(f"  {message}"),
        command=command,
    )


def build_default_detector(
    work: Path,
    out: Path,
    *,
    real: Path = REAL_TRAIN,
    held_out: Path = REAL_HELD_OUT,
    settings: BuildSettings | None = None,
    base_config: DetectorTrainConfig | None = None,
    say: Say = print,
) -> dict:
    """Steps 1–3 of the module's note; the shipped model's metadata. Each step's result is
    kept in ``work`` and reused. ``base_config``: how the simulator-only detector trains
    (default: as ``vista tracking train`` does)."""
    from services.tracking.detector_training import DetectorTrainConfig

    settings = settings or BuildSettings()
    for folder in (real, held_out):
        if not folder.is_dir():
            raise ValueError(f"{folder}: no such folder (the real labelled scans the model needs)")
    say(
        f"simulating what {work / 'train'} lacks ({settings.drives} drives of "
        f"{settings.frames} frames)"
    )
    sim = simulated_drives(work / "train", settings.drives, settings.frames, say)
    base = simulator_only(
        sim,
        work / "detector-sim.onnx",
        replace(base_config or DetectorTrainConfig(), seed=settings.seed),
        work,
        say,
    )
    return fine_tuned(
        base,
        [real],
        out,
        validate_on=[held_out],
        paste_from=sim,
        seed=settings.seed,
        work=work,
        say=say,
        epochs=settings.tune_epochs,
        windows=settings.tune_windows,
        command=settings.command(),
    )
