"""The road under a LiDAR scan: each point's height above the ground.

The lowest return of each 2 m cell is a ground candidate; a plane is fitted to them by
RANSAC (the sensor on a car sees mostly road, and the plane's height under the sensor is
its mounting height), then each cell's ground is the median of the plausible candidates
in its 5 × 5 neighbourhood, so a gentle rise, a crown or a kerb stays ground while a car's
roof does not.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

CELL_M = 2.0
EXTENT_M = 80.0
PLAUSIBLE_M = 0.45
"""How far above or below the fitted plane a cell's lowest return may be and still be ground."""


@dataclass(frozen=True)
class Ground:
    plane: np.ndarray
    """(4,) a, b, c, d with a·x + b·y + c·z + d = 0, (a, b, c) a unit normal pointing up."""
    cell_height_m: np.ndarray
    """(G, G) the ground's z under each cell (the plane's where the cell saw no ground)."""

    def height(self, points: np.ndarray) -> np.ndarray:
        """(N,) metres above the ground of (N, ≥3) points (LiDAR frame)."""
        i, j = _cell(points)
        inside = (
            (i >= 0)
            & (i < self.cell_height_m.shape[0])
            & (j >= 0)
            & (j < self.cell_height_m.shape[1])
        )
        plane_z = (
            -(self.plane[0] * points[:, 0] + self.plane[1] * points[:, 1] + self.plane[3])
            / self.plane[2]
        )
        local = self.cell_height_m[
            np.clip(i, 0, self.cell_height_m.shape[0] - 1),
            np.clip(j, 0, self.cell_height_m.shape[1] - 1),
        ]
        return points[:, 2] - np.where(inside, local, plane_z)


def _cell(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    i = np.floor((points[:, 0] + EXTENT_M) / CELL_M).astype(np.int64)
    j = np.floor((points[:, 1] + EXTENT_M) / CELL_M).astype(np.int64)
    return i, j


def _plane_ransac(
    candidates: np.ndarray, rng: np.random.Generator, hypotheses: int = 200
) -> np.ndarray:
    """The plane most candidates lie within 0.15 m of, refitted by least squares to them."""
    picks = rng.integers(0, len(candidates), size=(hypotheses, 3))
    a, b, c = candidates[picks[:, 0]], candidates[picks[:, 1]], candidates[picks[:, 2]]
    normal = np.cross(b - a, c - a)
    length = np.linalg.norm(normal, axis=1)
    good = (length > 1e-6) & (np.abs(normal[:, 2]) > 0.9 * np.maximum(length, 1e-12))
    if not good.any():
        return np.array([0.0, 0.0, 1.0, -candidates[:, 2].min()])
    normal = normal[good] / length[good, None]
    normal *= np.sign(normal[:, 2:3])
    offset = -np.einsum("ij,ij->i", normal, a[good])
    distance = np.abs(candidates @ normal.T + offset)
    best = int((distance < 0.15).sum(axis=0).argmax())
    inliers = candidates[distance[:, best] < 0.15]
    design = np.column_stack([inliers[:, 0], inliers[:, 1], np.ones(len(inliers))])
    (gx, gy, gz), *_ = np.linalg.lstsq(design, inliers[:, 2], rcond=None)  # z = gx x + gy y + gz
    plane = np.array([-gx, -gy, 1.0, -gz])
    return plane / np.linalg.norm(plane[:3])


def estimate_ground(points: np.ndarray, seed: int = 0) -> Ground:
    """The ground of a scan: points (N, ≥3), metres, LiDAR frame."""
    xyz = np.asarray(points[:, :3], dtype=np.float64)
    size = int(2 * EXTENT_M / CELL_M)
    i, j = _cell(xyz)
    inside = (i >= 0) & (i < size) & (j >= 0) & (j < size)
    flat = i[inside] * size + j[inside]
    lowest = np.full(size * size, np.inf)
    np.minimum.at(lowest, flat, xyz[inside, 2])
    seen = np.isfinite(lowest)
    cells = np.flatnonzero(seen)
    centres = np.column_stack(
        [
            (cells // size + 0.5) * CELL_M - EXTENT_M,
            (cells % size + 0.5) * CELL_M - EXTENT_M,
            lowest[cells],
        ]
    )
    if len(centres) < 3:
        return Ground(np.array([0.0, 0.0, 1.0, 1.73]), np.full((size, size), -1.73))
    plane = _plane_ransac(centres, np.random.default_rng(seed))
    plane_z = -(plane[0] * centres[:, 0] + plane[1] * centres[:, 1] + plane[3]) / plane[2]
    plausible = np.abs(centres[:, 2] - plane_z) < PLAUSIBLE_M
    residual = np.full(size * size, np.nan)
    residual[cells[plausible]] = centres[plausible, 2] - plane_z[plausible]
    grid = residual.reshape(size, size)
    # the median of a 5 × 5 neighbourhood's plausible residuals (nan where none)
    filled = _nan_median(grid, 5)
    xs = (np.arange(size) + 0.5) * CELL_M - EXTENT_M
    plane_grid = -(plane[0] * xs[:, None] + plane[1] * xs[None, :] + plane[3]) / plane[2]
    return Ground(plane, plane_grid + np.nan_to_num(filled, nan=0.0))


def _nan_median(grid: np.ndarray, window: int) -> np.ndarray:
    """The median of each cell's ``window`` × ``window`` neighbourhood, ignoring nans."""
    pad = window // 2
    padded = np.pad(grid, pad, constant_values=np.nan)
    views = np.lib.stride_tricks.sliding_window_view(padded, (window, window))
    stacked = views.reshape(grid.shape[0], grid.shape[1], -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "All-NaN slice": no ground seen there
        return np.nanmedian(stacked, axis=-1)
