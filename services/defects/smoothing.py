"""Gaussian smoothing of height-map arrays, compiled and without the GIL.

``scipy.ndimage.gaussian_filter`` holds the GIL while it filters: one of the reasons the
panels' surface work, which smooths a lot, ran no faster on two threads than on one.
``gaussian_pair`` filters two arrays alike (a normalised smoothing's weighted values and weights) exactly
as ``gaussian_filter(…, sigma, truncate=3.0)`` does with its default ``reflect`` edges.
"""

from __future__ import annotations

import numpy as np
from numba import njit

TRUNCATE = 3.0
"""The kernel reaches this many σ (rounded to whole cells), as SciPy's ``truncate``."""


def gaussian_kernel(sigma: float) -> np.ndarray:
    """SciPy's sampled Gaussian: exp(−x² / 2σ²) for |x| ≤ ⌊TRUNCATE·σ + ½⌋, summing to 1."""
    radius = int(TRUNCATE * sigma + 0.5)
    x = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    return kernel / kernel.sum()


def gaussian_pair(a: np.ndarray, b: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Two (rows, cols) arrays of one dtype smoothed with a Gaussian of ``sigma`` cells
    (edges mirrored: ``reflect``); sums in float64, results in the arrays' dtype."""
    if a.shape != b.shape or a.dtype != b.dtype:
        raise ValueError("gaussian_pair needs two arrays of one shape and dtype")
    return _gaussian_pair(a, b, gaussian_kernel(sigma))


@njit(cache=True, nogil=True, inline="always")
def _reflect(i: int, n: int) -> int:
    """Index i of the infinite mirror extension (d c b a | a b c d | d c b a) of n cells."""
    i %= 2 * n
    return i if i < n else 2 * n - 1 - i


@njit(cache=True, nogil=True)
def _gaussian_pair(
    a: np.ndarray, b: np.ndarray, kernel: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = a.shape
    taps = kernel.shape[0]
    radius = taps // 2
    # Along the rows, then along the columns (SciPy's order and, like it, the first pass
    # stored in the arrays' dtype); each output row summed in float64 as whole-row
    # multiply-adds, which the compiler vectorises. The first pass is kept for the
    # ``taps`` rows an output row needs only (a ring of rows, row k in slot k % taps): it
    # stays in the core's cache instead of making a round trip through memory.
    ring_a = np.empty((taps, cols), a.dtype)
    ring_b = np.empty((taps, cols), b.dtype)
    line_a = np.empty(cols + 2 * radius)
    line_b = np.empty(cols + 2 * radius)
    sum_a = np.empty(cols)
    sum_b = np.empty(cols)
    out_a = np.empty((rows, cols), a.dtype)
    out_b = np.empty((rows, cols), b.dtype)
    ready = 0  # rows of the first pass done
    for i in range(rows):
        # Output row i reads the first pass's rows within ``radius`` of it (mirrored at
        # the map's edges: rows on the same side).
        while ready < min(rows, i + radius + 1):
            across(a, b, kernel, ready, line_a, line_b, sum_a, sum_b)
            ring_a[ready % taps] = sum_a
            ring_b[ready % taps] = sum_b
            ready += 1
        down(ring_a, ring_b, kernel, i, rows, sum_a, sum_b)
        out_a[i] = sum_a
        out_b[i] = sum_b
    return out_a, out_b


@njit(cache=True, nogil=True, inline="always")
def down(
    ring_a: np.ndarray,
    ring_b: np.ndarray,
    kernel: np.ndarray,
    i: int,
    rows: int,
    sum_a: np.ndarray,
    sum_b: np.ndarray,
) -> None:
    """Row i of a and b smoothed down the columns, into ``sum_a`` and ``sum_b`` (float64),
    from the ring of rows smoothed ``across`` (row k in slot k % taps) of a map of
    ``rows`` rows."""
    taps = kernel.shape[0]
    radius = taps // 2
    sum_a[:] = 0.0
    sum_b[:] = 0.0
    for t in range(taps):
        w = kernel[t]
        k = _reflect(i + t - radius, rows) % taps
        for j in range(ring_a.shape[1]):
            sum_a[j] += w * ring_a[k, j]
            sum_b[j] += w * ring_b[k, j]


@njit(cache=True, nogil=True, inline="always")
def across(
    a: np.ndarray,
    b: np.ndarray,
    kernel: np.ndarray,
    i: int,
    line_a: np.ndarray,
    line_b: np.ndarray,
    sum_a: np.ndarray,
    sum_b: np.ndarray,
) -> None:
    """Row i of a and b smoothed along the row, into ``sum_a`` and ``sum_b`` (float64)."""
    cols = a.shape[1]
    taps = kernel.shape[0]
    radius = taps // 2
    # The row with its mirrored ends: only the ends need the mirror's index arithmetic.
    line_a[radius : radius + cols] = a[i]
    line_b[radius : radius + cols] = b[i]
    for j in range(radius):
        left, right = _reflect(j - radius, cols), _reflect(cols + j, cols)
        line_a[j], line_b[j] = a[i, left], b[i, left]
        line_a[radius + cols + j], line_b[radius + cols + j] = a[i, right], b[i, right]
    sum_a[:] = 0.0
    sum_b[:] = 0.0
    for t in range(taps):
        w = kernel[t]
        for j in range(cols):
            sum_a[j] += w * line_a[j + t]
            sum_b[j] += w * line_b[j + t]
