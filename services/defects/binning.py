"""Compiled passes over the points: one to bin them into the height map (count, height and
colour sums together), one to gather the points of chosen cells, one to take a seam's
section slabs; and the bounds of an even sample of them.

A stitched assembly is ~100 M points per m² at 0.1 mm spacing; each numpy pass over them
costs more than the whole budget allows, so these three loops are compiled (numba) and
read each point once. They run without the GIL and hold no state, so jobs in threads may
call them at the same time. Every pass computes a point's cell with ``_uvw`` and
``_cell_of``, so the cells of the gather are exactly those of the binning; points outside
the grid (not finite, or strays beyond the sampled extent) belong to no cell.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

WORKERS = min(2, os.cpu_count() or 1)
"""Threads for the passes over all points (each takes a share of the points)."""


def _in_shares(task: Callable[[slice], tuple], n: int) -> list[tuple]:
    shares = [slice(i * n // WORKERS, (i + 1) * n // WORKERS) for i in range(WORKERS)]
    if WORKERS == 1:
        return [task(shares[0])]
    with ThreadPoolExecutor(WORKERS) as pool:
        return list(pool.map(task, shares))


def uv_bounds(
    points: np.ndarray, origin: np.ndarray, axes: np.ndarray, stride: int = 8
) -> np.ndarray:
    """(u_min, u_max, v_min, v_max) of every ``stride``-th finite point of (N, 3) points
    in the frame (origin, axes rows u, v): neighbouring points follow each other in a
    scanned or voxel-merged cloud, so the sample misses the extent by about ``stride``
    point spacings at most."""
    return _uv_bounds(points[::stride], origin, axes)


def bin_points(
    points: np.ndarray,
    colors: np.ndarray | None,
    origin: np.ndarray,
    axes: np.ndarray,
    grid: np.ndarray,
    shape: tuple[int, int],
    block: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Per cell of a ``shape`` grid (``grid`` = u0, v0, 1 / cell): point count and sum of
    heights w (axes row 2); per block of ``block`` × ``block`` cells: point count and the
    sum of the (N, 3) ``colors`` (None without colours). Points outside the grid are
    left out."""
    no_colors = np.zeros((0, 3), np.uint8)
    parts = _in_shares(
        lambda share: _bin_points(
            points[share],
            no_colors if colors is None else colors[share],
            origin,
            axes,
            grid,
            shape,
            block,
        ),
        len(points),
    )
    count, height, block_count, color = parts[0]
    for part in parts[1:]:  # in place: no fresh (page-faulting) arrays of the grid's size
        for total, share in zip((count, height, block_count, color), part, strict=True):
            total += share
    return count, height, block_count, None if colors is None else color


@njit(cache=True, nogil=True, inline="always")
def _transform(origin: np.ndarray, axes: np.ndarray, grid: np.ndarray) -> tuple:
    """The frame and grid as scalars, read once: loads from arrays inside a loop that also
    stores cannot be hoisted by the compiler (the arrays might alias)."""
    a = axes
    rows = (a[0, 0], a[0, 1], a[0, 2]) + (a[1, 0], a[1, 1], a[1, 2]) + (a[2, 0], a[2, 1], a[2, 2])
    return (origin[0], origin[1], origin[2]) + rows + (grid[0], grid[1], grid[2])


@njit(cache=True, nogil=True, inline="always")
def _uvw(points: np.ndarray, i: int, t: tuple) -> tuple[float, float, float]:
    x, y, z = points[i, 0] - t[0], points[i, 1] - t[1], points[i, 2] - t[2]
    return (
        x * t[3] + y * t[4] + z * t[5],
        x * t[6] + y * t[7] + z * t[8],
        x * t[9] + y * t[10] + z * t[11],
    )


@njit(cache=True, nogil=True, inline="always")
def _cell_of(u: float, v: float, t: tuple, rows: int, cols: int) -> int:
    """Flat index of the cell holding (u, v), −1 outside the grid (or not finite);
    ``t[12:15]`` = (u0, v0, 1 / cell)."""
    row, col = (u - t[12]) * t[14], (v - t[13]) * t[14]
    if not (0.0 <= row < rows and 0.0 <= col < cols):
        return -1
    return np.int64(row) * cols + np.int64(col)


@njit(cache=True, nogil=True)
def _uv_bounds(points: np.ndarray, origin: np.ndarray, axes: np.ndarray) -> np.ndarray:
    t = _transform(origin, axes, np.zeros(3))
    u_min, u_max, v_min, v_max = np.inf, -np.inf, np.inf, -np.inf
    for i in range(points.shape[0]):
        u, v, w = _uvw(points, i, t)
        if abs(u) + abs(v) + abs(w) < np.inf:
            u_min, u_max = min(u_min, u), max(u_max, u)
            v_min, v_max = min(v_min, v), max(v_max, v)
    return np.array([u_min, u_max, v_min, v_max])


@njit(cache=True, nogil=True)
def _bin_points(
    points: np.ndarray,
    colors: np.ndarray,
    origin: np.ndarray,
    axes: np.ndarray,
    grid: np.ndarray,
    shape: tuple[int, int],
    block: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per cell of a ``shape`` grid: point count and sum of heights w (axes row 2); per
    block of ``block`` × ``block`` cells: point count and, if ``colors`` has a row per
    point, the sum of the colour channels (else a (0, 3) array); points outside the grid
    are left out."""
    rows, cols = shape
    count = np.zeros(rows * cols, np.int32)
    height = np.zeros(rows * cols, np.float32)  # a few heights of ±tens of mm: ample
    block_cols = -(-cols // block)
    block_count = np.zeros(-(-rows // block) * block_cols, np.int32)
    with_color = colors.shape[0] == points.shape[0]
    color = np.zeros((block_count.shape[0] if with_color else 0, 3), np.float64)
    t = _transform(origin, axes, grid)
    block_scale = t[14] / block
    for i in range(points.shape[0]):
        u, v, w = _uvw(points, i, t)
        cell = _cell_of(u, v, t, rows, cols)
        if cell < 0:
            continue
        count[cell] += 1
        height[cell] += w
        # As the cell, scaled: no integer division in the loop.
        b = np.int64((u - t[12]) * block_scale) * block_cols + np.int64((v - t[13]) * block_scale)
        block_count[b] += 1
        if with_color:
            color[b, 0] += colors[i, 0]
            color[b, 1] += colors[i, 1]
            color[b, 2] += colors[i, 2]
    return count, height, block_count, color


@njit(cache=True, nogil=True)
def gather_cells(
    points: np.ndarray,
    origin: np.ndarray,
    axes: np.ndarray,
    grid: np.ndarray,
    shape: tuple[int, int],
    slot: np.ndarray,
    offsets: np.ndarray,
) -> np.ndarray:
    """Indices of the points in the chosen cells, grouped by cell: ``slot`` maps a flat
    cell to its place among the chosen ones (−1 if not chosen), and the points of chosen
    cell s go to [offsets[s], offsets[s + 1]) in point order."""
    rows, cols = shape
    order = np.empty(offsets[-1], np.int64)
    fill = offsets[:-1].copy()
    t = _transform(origin, axes, grid)
    for i in range(points.shape[0]):
        u, v, _ = _uvw(points, i, t)
        cell = _cell_of(u, v, t, rows, cols)
        s = slot[cell] if cell >= 0 else -1
        if s >= 0:
            order[fill[s]] = i
            fill[s] += 1
    return order


@njit(cache=True, nogil=True)
def slab_points(
    points: np.ndarray,
    chosen: np.ndarray,
    origin: np.ndarray,
    axes: np.ndarray,
    line: np.ndarray,
    sections: np.ndarray,
) -> np.ndarray:
    """The ``chosen`` points lying in a seam's section slabs, as (4, M) rows: section k,
    y along the seam from its section's plane, x across the seam, height w.

    ``line`` = (u, v of the seam's centre, direction u, v); ``sections`` = (position of
    section 0 along the line, pitch, count, half slab width, reach across the line)."""
    t = _transform(origin, axes, np.zeros(3))
    cu, cv, du, dv = line[0], line[1], line[2], line[3]
    first, pitch, count, half_slab, reach = (
        sections[0],
        sections[1],
        sections[2],
        sections[3],
        sections[4],
    )
    slab = np.empty((4, chosen.shape[0]))
    n = 0
    for j in range(chosen.shape[0]):
        u, v, w = _uvw(points, chosen[j], t)
        along = (u - cu) * du + (v - cv) * dv
        across = (v - cv) * du - (u - cu) * dv
        k = np.rint((along - first) / pitch)
        y = along - (first + k * pitch)
        if 0 <= k < count and abs(y) <= half_slab and abs(across) < reach:
            slab[0, n], slab[1, n], slab[2, n], slab[3, n] = k, y, across, w
            n += 1
    return slab[:, :n]
