"""Organized scans: neighbours and normals straight from the sensor's grid, no KD-tree.

grid : (rows, columns, 3) float32, mm; a pixel the sensor did not measure is all NaN.
"""

from __future__ import annotations

import numpy as np


def shifted(grid: np.ndarray, d_row: int, d_col: int) -> np.ndarray:
    """``out[r, c] = grid[r + d_row, c + d_col]``, NaN where that falls outside the grid."""
    out = np.full_like(grid, np.nan)
    rows, cols = grid.shape[:2]
    src_r = slice(max(d_row, 0), rows + min(d_row, 0))
    dst_r = slice(max(-d_row, 0), rows + min(-d_row, 0))
    src_c = slice(max(d_col, 0), cols + min(d_col, 0))
    dst_c = slice(max(-d_col, 0), cols + min(-d_col, 0))
    out[dst_r, dst_c] = grid[src_r, src_c]
    return out


def window_offsets(radius_px: int) -> list[tuple[int, int]]:
    """The (2r+1)² − 1 neighbours of a pixel in a square window."""
    span = range(-radius_px, radius_px + 1)
    return [(r, c) for r in span for c in span if (r, c) != (0, 0)]


def _difference(grid: np.ndarray, d_row: int, d_col: int) -> np.ndarray:
    """The surface's step along one grid axis at each pixel: the central difference where
    both neighbours were measured, else the one-sided difference to the one that was (at
    a scan's border, or beside a pixel without a return: the last pixel of a panel's top
    before its unseen side face keeps a normal, and with it its place in the stitch).
    NaN with neither."""
    forward = shifted(grid, d_row, d_col) - grid
    backward = grid - shifted(grid, -d_row, -d_col)
    central = (forward + backward) / 2
    central = np.where(np.isfinite(central), central, forward)
    return np.where(np.isfinite(central), central, backward)


def grid_normals(grid: np.ndarray, *, step_px: int = 1) -> np.ndarray:
    """(rows, columns, 3) unit normals from differences ``step_px`` pixels apart (central,
    or one-sided at borders and beside missing pixels), turned towards the sensor (the
    frame's origin); NaN where a pixel has no neighbour along an axis."""
    along_cols = _difference(grid, 0, step_px)
    along_rows = _difference(grid, step_px, 0)
    normals = np.cross(along_cols, along_rows)
    length = np.linalg.norm(normals, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = normals / length
    facing_away = np.sum(normals * grid, axis=-1) > 0
    normals[facing_away] *= -1
    return normals.astype(np.float32)


def surrounded(grid: np.ndarray) -> np.ndarray:
    """(rows, columns) bool: pixels whose four neighbours were measured (no border or
    hole beside them): the ones whose normals point-to-plane alignment can trust."""
    measured = np.isfinite(grid).all(axis=-1)
    inner = measured.copy()
    for d_row, d_col in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        inner &= np.isfinite(shifted(grid, d_row, d_col)).all(axis=-1)
    return inner


def grid_spacing_mm(grid: np.ndarray) -> float:
    """Median distance between measured neighbours along a row (NaN if there are none)."""
    rows = grid[:: max(1, grid.shape[0] // 64)]
    steps = np.linalg.norm(rows[:, 1:] - rows[:, :-1], axis=-1)
    steps = steps[np.isfinite(steps)]
    return float(np.median(steps)) if len(steps) else float("nan")


def smooth_grid_normals(grid: np.ndarray, span_mm: float) -> np.ndarray:
    """``grid_normals`` over differences about ``span_mm`` long (less noise than adjacent
    pixels give), falling back to adjacent pixels where the wide stencil has no
    neighbour."""
    spacing = grid_spacing_mm(grid)
    step = int(round(span_mm / (2 * spacing))) if np.isfinite(spacing) and spacing > 0 else 1
    normals = grid_normals(grid)
    if step > 1:
        wide = grid_normals(grid, step_px=step)
        known = np.isfinite(wide).all(axis=-1)
        normals[known] = wide[known]
    return normals
