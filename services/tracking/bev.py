"""A LiDAR scan as a bird's-eye-view image for the learned detector: 0.2 m cells over a
window of the ground plane (rows along x, columns along y), twelve channels a cell —

- 0–7: whether any return falls in each 0.5 m slice of height from 2.5 m below the sensor
  to 1.5 m above it (a car's outline, its roof, what stands over it);
- 8: the highest return's height, scaled to 0–1 over the same span;
- 9: how many returns, log-scaled (1 at 64);
- 10: the cell's distance from the sensor / 80 m (how sparse a car there looks);
- 11: the highest return's height above the lowest return within ``FLOOR_M`` around —
  the height over the local ground, the same on a slope or an embankment as on the flat
  (divided by ``FLOOR_SCALE_M`` = 3 m, at most 1).

Reflectance is left out on purpose: each sensor scales it its own way, and a detector
trained on simulated scans learned "dark is a car" from it (KITTI's car paint reads mostly
0), which real roads and walls — often 0 too — then contradicted.

The full view is KITTI's detection range, x 0–70.4 m and y ±40 m (352 × 400 cells); a
window is any part of the plane, its sides multiples of ``ALIGN`` cells so that the
network's strides divide it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CELL_M = 0.2
CHANNELS = 12
SLICES = 8
Z_LOW_M, Z_HIGH_M = -2.5, 1.5
ALIGN = 16
STRIDE = 4
"""The network's output cell is STRIDE input cells (0.8 m)."""
RANGE_SCALE_M = 80.0
FLOOR_M = 4.2
FLOOR_SCALE_M = 3.0
FULL_VIEW = (0.0, -40.0, 70.4, 40.0)


@dataclass(frozen=True)
class Window:
    """A rectangle of the ground plane: x from ``x0_m``, y from ``y0_m``, ``rows`` × ``cols``
    cells of ``CELL_M``."""

    x0_m: float
    y0_m: float
    rows: int
    cols: int

    @classmethod
    def around(cls, region: tuple[float, float, float, float] | np.ndarray) -> Window:
        """The aligned window covering ``region`` (x0, y0, x1, y1), its corner on the
        output grid (so a window's cells are the full view's cells)."""
        x0, y0, x1, y1 = (float(v) for v in region)
        step = CELL_M * STRIDE
        x0, y0 = np.floor(x0 / step) * step, np.floor(y0 / step) * step
        rows = int(np.ceil((x1 - x0) / CELL_M / ALIGN) * ALIGN)
        cols = int(np.ceil((y1 - y0) / CELL_M / ALIGN) * ALIGN)
        return cls(float(x0), float(y0), rows, cols)

    def cell_centres(self, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """x (rows,) and y (cols,) of the centres of the cells of ``stride`` input cells."""
        size = CELL_M * stride
        return (
            self.x0_m + (np.arange(self.rows // stride) + 0.5) * size,
            self.y0_m + (np.arange(self.cols // stride) + 0.5) * size,
        )


def encode(points: np.ndarray, window: Window) -> np.ndarray:
    """(12, rows, cols) float32 image of points (N, ≥3: x y z …, metres)."""
    from scipy.ndimage import minimum_filter

    row = np.floor((points[:, 0] - window.x0_m) / CELL_M).astype(np.int64)
    col = np.floor((points[:, 1] - window.y0_m) / CELL_M).astype(np.int64)
    z = points[:, 2]
    keep = (
        (row >= 0)
        & (row < window.rows)
        & (col >= 0)
        & (col < window.cols)
        & (z >= Z_LOW_M)
        & (z < Z_HIGH_M)
    )
    row, col, z = row[keep], col[keep], z[keep]
    cells = window.rows * window.cols
    flat = row * window.cols + col
    image = np.zeros((CHANNELS, cells), dtype=np.float32)
    slice_index = np.clip(
        ((z - Z_LOW_M) / ((Z_HIGH_M - Z_LOW_M) / SLICES)).astype(np.int64), 0, SLICES - 1
    )
    image[slice_index, flat] = 1.0
    # each cell's lowest and highest return: sorted by cell, then by height
    order = np.lexsort((z, flat))
    occupied, first = np.unique(flat[order], return_index=True)
    last = np.append(first[1:], len(order))[: len(first)] - 1  # none when no point is in
    top, lowest = np.full(cells, -np.inf), np.full(cells, np.inf)
    top[occupied], lowest[occupied] = z[order[last]], z[order[first]]
    seen = np.isfinite(top)
    image[8, seen] = (top[seen] - Z_LOW_M) / (Z_HIGH_M - Z_LOW_M)
    count = np.bincount(flat, minlength=cells).astype(np.float32)
    image[9] = np.log1p(count) / np.log(65.0)
    xs, ys = window.cell_centres()
    image[10] = (np.hypot(xs[:, None], ys[None, :]) / RANGE_SCALE_M).ravel()
    side = int(round(FLOOR_M / CELL_M)) | 1
    floor = minimum_filter(
        lowest.reshape(window.rows, window.cols), size=side, mode="nearest"
    ).ravel()
    image[11, seen] = np.clip((top[seen] - floor[seen]) / FLOOR_SCALE_M, 0.0, 1.0)
    return image.reshape(CHANNELS, window.rows, window.cols)
