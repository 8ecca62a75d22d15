"""The depth service's sample run (``contract.samples``): two frames of a simulated drive
in KITTI's camera, their depth predicted by the shipped model."""

from __future__ import annotations

from pathlib import Path

from contract.samples import SampleRun, SampleStep, Upload
from services.depth.simulate import simulate_drive

SAMPLE_FRAMES = 2


def sample_run(work: Path, frames: int, real_data: Path | None = None) -> SampleRun:
    folder = simulate_drive(work / "street", frames=SAMPLE_FRAMES, seed=1)
    images = sorted((folder / "image_02").rglob("*.png"))[:SAMPLE_FRAMES]
    uploads = {f"image-{k}": Upload(path, "image", "image/png") for k, path in enumerate(images)}
    return SampleRun(
        uploads=uploads,
        steps=(SampleStep("depth", "depth.predict", tuple(uploads)),),
        about=f"{len(images)} frames of a simulated street in KITTI's camera (1242 × 375)",
    )
