"""A sequence's frames: the PNG files of a folder, in name order, read as grey images of
the size its camera says."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from services.odometry.camera import FloorCamera


def frame_files(folder: Path) -> list[Path]:
    """The frames in name order; ValueError when there are fewer than two."""
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder of frames")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png")
    if len(files) < 2:
        raise ValueError(f"{folder}: needs at least 2 PNG frames, found {len(files)}")
    return files


def read_frames(files: list[Path], camera: FloorCamera) -> Iterator[np.ndarray]:
    for path in files:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ValueError(f"{path}: not an image OpenCV can read")
        if image.shape != (camera.height, camera.width):
            raise ValueError(
                f"{path}: {image.shape[1]} × {image.shape[0]} pixels, but camera.json says "
                f"{camera.width} × {camera.height}"
            )
        yield image
