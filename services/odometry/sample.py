"""The odometry service's sample run (``contract.samples``): a simulated floor sequence,
vista's method on it and OE-Net trained on it for one epoch."""

from __future__ import annotations

from pathlib import Path

from contract.samples import SampleRun, SampleStep, Upload
from services.odometry.camera import FloorCamera
from services.odometry.sequence import write_sequence_archive
from services.odometry.simulate import simulate_sequence

SAMPLE_CAMERA = FloorCamera(width=200, height=150, fps=60.0, mm_per_px=0.6)


def sample_run(work: Path, frames: int, real_data: Path | None = None) -> SampleRun:
    folder = work / "floor-sequence"
    seconds = frames / SAMPLE_CAMERA.fps
    simulate_sequence(
        folder, floor="asphalt", path="lawnmower", seconds=seconds, seed=5, camera=SAMPLE_CAMERA
    )
    archive = write_sequence_archive(folder, work / "floor-sequence.tar.gz")
    return SampleRun(
        uploads={"sequence": Upload(archive, "frames", "application/gzip")},
        steps=(
            SampleStep("odometry", "odometry.run", ("sequence",)),
            SampleStep(
                "oenet", "odometry.train", ("sequence",), {"epochs": 2, "batch": 8, "device": "cpu"}
            ),
        ),
        about=f"a simulated floor sequence of {frames} frames (200 × 150 px over asphalt)",
    )
