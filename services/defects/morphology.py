"""Square (chessboard) erosion and dilation of masks as runs of whole-array boolean
operations on shifted views: separable, ⌈log₂ width⌉ operations per axis (SciPy's
binary morphology and min/max filters on masks cost ~8× more on the height maps)."""

from __future__ import annotations

import numpy as np


def _window_all(mask: np.ndarray, width: int, axis: int, outside: bool) -> np.ndarray:
    """out[i] = all(mask[i − width // 2 … i + width // 2]) along ``axis`` (odd ``width``),
    cells beyond the edge counting as ``outside``."""
    half = width // 2
    m = np.moveaxis(mask, axis, 0)
    n = m.shape[0]
    padded = np.full((n + 2 * half, *m.shape[1:]), outside, dtype=bool)
    padded[half : half + n] = m
    # acc[i] = all(padded[i : i + span]); two overlapping spans cover a window.
    acc, span = padded, 1
    while span * 2 <= width:
        acc = acc[:-span] & acc[span:]
        span *= 2
    out = acc[:n] & acc[width - span : width - span + n]
    return np.moveaxis(out, 0, axis)


def erode(mask: np.ndarray, radius: int) -> np.ndarray:
    """Cells of ``mask`` whose (2·radius + 1)² square lies in it (outside is not)."""
    width = 2 * radius + 1
    return _window_all(_window_all(mask, width, 0, False), width, 1, False)


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Cells within ``radius`` (chessboard) of a cell of ``mask``."""
    width = 2 * radius + 1
    return ~_window_all(_window_all(~mask, width, 0, True), width, 1, True)
