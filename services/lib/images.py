"""Camera images as (H, W, 3) uint8 RGB arrays, read from and written to PNG or JPEG."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def read_image(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB from a PNG or JPEG (grey, 16-bit and RGBA converted)."""
    import cv2

    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ValueError(f"{path}: not a readable image")
    if raw.dtype == np.uint16:
        raw = (raw // 257).astype(np.uint8)
    if raw.dtype != np.uint8:
        raise ValueError(f"{path}: {raw.dtype} pixels (8- or 16-bit images only)")
    if raw.ndim == 2:
        return np.repeat(raw[..., None], 3, axis=2)
    if raw.shape[2] == 4:
        raw = raw[..., :3]
    return np.ascontiguousarray(raw[..., ::-1])


def write_image(path: Path, image: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.ascontiguousarray(image[..., ::-1])):
        raise ValueError(f"{path}: could not write the image")
