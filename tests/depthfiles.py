"""Small depth-service files for tests: a simulated drive packed as an archive, a tiny
depth model as ONNX with vista's spec."""

from __future__ import annotations

import tarfile
from pathlib import Path

import numpy as np


def small_drive(folder: Path, *, frames: int = 3, stereo: bool = True, seed: int = 1) -> Path:
    """A simulated drive at 128 × 64 in KITTI's layout."""
    from services.depth.camera import kitti_camera
    from services.depth.simulate import simulate_drive

    return simulate_drive(
        folder, frames=frames, stereo=stereo, seed=seed, camera=kitti_camera().resized(128, 64)
    )


def pack_drive(folder: Path, out: Path) -> Path:
    """``folder``'s contents as a tar.gz (the drive at the archive's top)."""
    with tarfile.open(out, "w:gz") as archive:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                archive.add(path, arcname=str(path.relative_to(folder)))
    return out


def tiny_depth_model(path: Path, *, width: int = 64, height: int = 32) -> Path:
    """A two-layer network answering depth in 2–50 m, exported with vista's depth spec."""
    import torch

    from services.depth.export import depth_metadata
    from services.lib.nn.onnx_io import export_onnx

    class Tiny(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.conv = torch.nn.Conv2d(3, 1, 3, padding=1)

        def forward(self, rgb: torch.Tensor) -> torch.Tensor:
            return 2 + 48 * torch.sigmoid(self.conv(rgb))

    torch.manual_seed(0)
    example = np.random.default_rng(0).random((1, 3, height, width), dtype=np.float32)
    metadata = depth_metadata("tiny", width, height, 84, {})
    export_onnx(Tiny().eval(), example, path, metadata, input_name="rgb", output_name="depth")
    return path
