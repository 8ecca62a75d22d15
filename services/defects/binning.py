"""Compiled passes over the points: one to bin them into the height map (count, height and
colour sums together, and the box of each run of points), one to take every seam's
section slabs; and the bounds and moments of an even sample of them.

A stitched assembly is ~100 M points per m² at 0.1 mm spacing; each numpy pass over them
costs more than the whole budget allows, so these loops are compiled (numba) and read
each point once. They run without the GIL and hold no state, so jobs in threads may call
them at the same time. Both passes compute a point's cell with ``_locate``, so the seam
pass sees exactly the cells of the binning; points outside the grid (not finite, or
strays beyond the sampled extent) belong to no cell. The seam pass reads only the runs of
consecutive points whose box, noted by the binning, comes near a seam (a sixth to a
third of them on a 2 × 2 assembly).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

CHUNK = 64
"""The binning notes the (u, v) box of each run of this many consecutive points, so that
later passes skip the runs far from what they look for (in a scanned or voxel-merged
cloud, consecutive points are neighbours)."""
TILE = 16
"""Cells along the side of the tiles that tell the seam pass which runs to read."""
CHANNEL_BITS = 21
"""The binning adds a point's three 8-bit colour channels to its block in one 64-bit
integer, each channel in a field this wide: exact while a block holds at most
``PACKED_MAX_POINTS`` points (at 0.1 mm spacing a 1 mm block holds about 100–300)."""
PACKED_MAX_POINTS = ((1 << CHANNEL_BITS) - 1) // 255


def _in_shares(task: Callable[[slice], tuple], n: int, workers: int) -> list[tuple]:
    """``task`` on ``workers`` threads, each on a share of n points starting at a whole
    chunk."""
    chunks = -(-n // CHUNK)
    bounds = [min(n, (i * chunks // workers) * CHUNK) for i in range(workers + 1)]
    shares = [slice(bounds[i], bounds[i + 1]) for i in range(workers)]
    if workers == 1:
        return [task(shares[0])]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(task, shares))


def uv_bounds(
    points: np.ndarray, origin: np.ndarray, axes: np.ndarray, stride: int = 8, workers: int = 1
) -> np.ndarray:
    """(u_min, u_max, v_min, v_max) of every ``stride``-th finite point of (N, 3) points
    in the frame (origin, axes rows u, v): neighbouring points follow each other in a
    scanned or voxel-merged cloud, so the sample misses the extent by about ``stride``
    point spacings at most. ``workers`` threads share the sample (it is read from all of
    the points' memory: a pass the size of the binning's)."""
    sample = points[::stride]
    parts = _in_shares(
        lambda share: (_uv_bounds(sample[share], origin, axes),), len(sample), workers
    )
    bounds = np.array([part[0] for part in parts])
    return np.array(
        [bounds[:, 0].min(), bounds[:, 1].max(), bounds[:, 2].min(), bounds[:, 3].max()]
    )


def sample_moments(
    points: np.ndarray, normals: np.ndarray | None, step: int
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Of every ``step``-th finite point of (N, 3) ``points``: their number, mean and
    (3, 3) covariance, and the sum of their finite (N, 3) ``normals`` (zeros without)."""
    no_normals = np.zeros((0, 3), np.float32)
    return _sample_moments(points, no_normals if normals is None else normals, step)


def seam_slabs(
    points: np.ndarray,
    origin: np.ndarray,
    axes: np.ndarray,
    grid: np.ndarray,
    count: np.ndarray,
    chunk_uv: np.ndarray,
    lines: np.ndarray,
    sections: np.ndarray,
    workers: int = 1,
) -> list[list[np.ndarray]]:
    """The points in each seam's section slabs, as pieces of (4, M) rows: section k, y
    along the seam from its section's plane, x across the seam, height w.

    Grid as for ``bin_points``, with its (rows, cols) point ``count`` and ``chunk_uv``
    boxes. Per seam, ``lines`` rows = (u, v of its centre, direction u, v, start, end
    along it) and ``sections`` rows = (position of section 0 along the line, pitch,
    number of sections, half slab width, reach across the line, and the thinning: the
    half width and the reach across within which every point is kept, and the stride of
    those kept beyond both — each ``stride``-th point of the cloud); slabs wider than the
    pitch overlap, and a point is in each that holds it. Only the runs of points
    whose box touches a tile near a seam (its band: cell centres within reach + one cell
    of the line) are read, on ``workers`` threads."""
    seam_of_cell, band_tiles, capacity = _seam_bands(grid, count, lines, sections)
    offsets = np.concatenate([[0], np.cumsum(capacity)])
    parts = _in_shares(
        lambda share: _seam_slabs(
            points[share],
            share.start,
            chunk_uv[share.start // CHUNK :],
            origin,
            axes,
            grid,
            seam_of_cell,
            band_tiles,
            lines,
            sections,
            offsets,
        ),
        len(points),
        workers,
    )
    return [
        [slab[:, offsets[s] : offsets[s] + filled[s]] for slab, filled in parts]
        for s in range(len(lines))
    ]


def bin_points(
    points: np.ndarray,
    colors: np.ndarray | None,
    origin: np.ndarray,
    axes: np.ndarray,
    grid: np.ndarray,
    shape: tuple[int, int],
    block: int,
    workers: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """Per cell of a ``shape`` grid (``grid`` = u0, v0, 1 / cell): point count and sum of
    heights w (axes row 2); per block of ``block`` × ``block`` cells: point count and the
    sum of the (N, 3) ``colors`` (None without colours); per ``CHUNK`` consecutive
    points: (u_min, u_max, v_min, v_max) of those in the grid (float32; min > max if
    none). Points outside the grid are left out. ``workers`` threads share the points."""
    no_colors = np.zeros((0, 3), np.uint8)

    def binned(packed: bool) -> list[tuple]:
        return _in_shares(
            lambda share: _bin_points(
                points[share],
                no_colors if colors is None else colors[share],
                origin,
                axes,
                grid,
                shape,
                block,
                packed,
            ),
            len(points),
            workers,
        )

    parts = binned(packed=True)
    count, height, color, _ = parts[0]
    for part in parts[1:]:  # in place: no fresh (page-faulting) arrays of the grid's size
        for total, share in zip((count, height, color), part[:3], strict=True):
            total += share
    chunk_uv = np.concatenate([part[3] for part in parts])
    block_count = _block_counts(count, shape, block)
    if colors is not None and block_count.max(initial=0) > PACKED_MAX_POINTS:
        # A cloud far denser than a scanner's: the packed colour sums may have run over.
        parts = binned(packed=False)
        color = np.sum([part[2] for part in parts], axis=0)  # whole numbers: exact
    return count, height, block_count, None if colors is None else color, chunk_uv


@njit(cache=True, nogil=True, inline="always")
def _transform(origin: np.ndarray, axes: np.ndarray, grid: np.ndarray) -> tuple:
    """The frame and grid as scalars, read once: loads from arrays inside a loop that also
    stores cannot be hoisted by the compiler (the arrays might alias)."""
    a = axes
    rows = (a[0, 0], a[0, 1], a[0, 2]) + (a[1, 0], a[1, 1], a[1, 2]) + (a[2, 0], a[2, 1], a[2, 2])
    return (origin[0], origin[1], origin[2]) + rows + (grid[0], grid[1], grid[2])


@njit(cache=True, nogil=True, inline="always")
def _uvw(px: float, py: float, pz: float, t: tuple) -> tuple[float, float, float]:
    """(u, v, w) of the cloud point (px, py, pz) in the frame ``t`` of ``_transform``."""
    x, y, z = px - t[0], py - t[1], pz - t[2]
    return (
        x * t[3] + y * t[4] + z * t[5],
        x * t[6] + y * t[7] + z * t[8],
        x * t[9] + y * t[10] + z * t[11],
    )


@njit(cache=True, nogil=True, inline="always")
def _locate(
    points: np.ndarray,
    start: int,
    run: int,
    t: tuple,
    rows: int,
    cols: int,
    xyz: np.ndarray,
    uvw: np.ndarray,
    cell: np.ndarray,
) -> None:
    """Of ``points[start : start + run]``: (u, v, w) in ``uvw[:, :run]``, and the flat
    index of the cell holding each in ``cell[:run]`` (−1 outside the grid, or not finite);
    ``t[12:15]`` = (u0, v0, 1 / cell). The points are first copied apart into ``xyz`` as
    float64, so that the second loop, free of branches, runs on vector registers (about
    4× the speed of a point at a time, the same arithmetic so the same values)."""
    block = points[start : start + run]
    for j in range(run):
        xyz[0, j], xyz[1, j], xyz[2, j] = block[j, 0], block[j, 1], block[j, 2]
    rows_f, cols_f = np.float64(rows), np.float64(cols)
    for j in range(run):
        u, v, w = _uvw(xyz[0, j], xyz[1, j], xyz[2, j], t)
        uvw[0, j], uvw[1, j], uvw[2, j] = u, v, w
        row, col = (u - t[12]) * t[14], (v - t[13]) * t[14]
        inside = (row >= 0.0) & (row < rows_f) & (col >= 0.0) & (col < cols_f)
        # Clamped before the conversion, whatever the point: a select, not a branch; to
        # 32 bits, which AVX2 converts four at a time (to 64 bits only AVX-512 does).
        r, c = np.int32(min(max(row, 0.0), rows_f - 1)), np.int32(min(max(col, 0.0), cols_f - 1))
        cell[j] = np.int64(r) * cols + c if inside else -1


@njit(cache=True, nogil=True)
def _uv_bounds(points: np.ndarray, origin: np.ndarray, axes: np.ndarray) -> np.ndarray:
    t = _transform(origin, axes, np.zeros(3))
    u_min, u_max, v_min, v_max = np.inf, -np.inf, np.inf, -np.inf
    for i in range(points.shape[0]):
        u, v, w = _uvw(points[i, 0], points[i, 1], points[i, 2], t)
        if abs(u) + abs(v) + abs(w) < np.inf:
            u_min, u_max = min(u_min, u), max(u_max, u)
            v_min, v_max = min(v_min, v), max(v_max, v)
    return np.array([u_min, u_max, v_min, v_max])


@njit(cache=True, nogil=True)
def _sample_moments(
    points: np.ndarray, normals: np.ndarray, step: int
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    with_normals = normals.shape[0] == points.shape[0]
    ref = np.zeros(3)  # sums about a point of the cloud: no cancellation far from 0
    found = False
    n = 0
    total = np.zeros(3)
    products = np.zeros((3, 3))
    towards = np.zeros(3)
    for i in range(0, points.shape[0], step):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if not abs(x) + abs(y) + abs(z) < np.inf:
            continue
        if not found:
            ref[0], ref[1], ref[2] = x, y, z
            found = True
        d = (x - ref[0], y - ref[1], z - ref[2])
        n += 1
        for a in range(3):
            total[a] += d[a]
            for b in range(3):
                products[a, b] += d[a] * d[b]
        if with_normals:
            nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
            if abs(nx) + abs(ny) + abs(nz) < np.inf:
                towards[0] += nx
                towards[1] += ny
                towards[2] += nz
    mean = total / max(n, 1)
    covariance = (products - n * np.outer(mean, mean)) / max(n - 1, 1)
    return n, ref + mean, covariance, towards


@njit(cache=True, nogil=True)
def _bin_points(
    points: np.ndarray,
    colors: np.ndarray,
    origin: np.ndarray,
    axes: np.ndarray,
    grid: np.ndarray,
    shape: tuple[int, int],
    block: int,
    packed: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per cell of a ``shape`` grid: point count and sum of heights w (axes row 2); per
    block of ``block`` × ``block`` cells, if ``colors`` has a row per point, the sum of the
    colour channels (else a (0, 3) array; ``packed``: all three in one integer addition
    per point, exact up to ``PACKED_MAX_POINTS`` in a block); points outside the grid are
    left out; and the (u, v) box of each ``CHUNK`` points in the grid.

    Each run of points is done in two loops: ``_locate`` computes where its points fall,
    the next adds them up (and their packed colours). The grid's additions then no longer
    hold back the arithmetic of the points after them."""
    rows, cols = shape
    count = np.zeros(rows * cols, np.int32)
    height = np.zeros(rows * cols, np.float32)  # a few heights of ±tens of mm: ample
    block_cols = -(-cols // block)
    with_color = colors.shape[0] == points.shape[0]
    color = np.zeros((-(-rows // block) * block_cols if with_color else 0, 3), np.float64)
    # Packed, the colours are added up per cell, beside the cell's count and height (the
    # cell's lines are at hand: a third of the cost of adding each point to its block),
    # and the cells' sums per block after the pass.
    by_cell = with_color and packed
    cell_rgb = np.zeros(rows * cols if by_cell else 0, np.int64)
    rgb = np.zeros(color.shape[0] if packed else 0, np.int64)
    bits = CHANNEL_BITS
    # A cell's block from two lookups: no integer division per point.
    block_of_row = (np.arange(rows) // block) * block_cols
    block_of_col = np.arange(cols) // block
    n = points.shape[0]
    chunk_uv = np.empty((-(-n // CHUNK), 4), np.float32)
    t = _transform(origin, axes, grid)
    xyz, uvw = np.empty((3, CHUNK)), np.empty((3, CHUNK))
    cells = np.empty(CHUNK, np.int64)
    for chunk in range(chunk_uv.shape[0]):
        start = chunk * CHUNK
        run = min(n, start + CHUNK) - start
        _locate(points, start, run, t, rows, cols, xyz, uvw, cells)
        u_min, u_max, v_min, v_max = np.inf, -np.inf, np.inf, -np.inf
        for j in range(run):
            c = cells[j]
            if c >= 0:
                count[c] += 1
                height[c] += uvw[2, j]
                u_min, u_max = min(u_min, uvw[0, j]), max(u_max, uvw[0, j])
                v_min, v_max = min(v_min, uvw[1, j]), max(v_max, uvw[1, j])
                if by_cell:
                    i = start + j
                    red, green, blue = colors[i, 0], colors[i, 1], colors[i, 2]
                    cell_rgb[c] += red | (np.int64(green) << bits) | (np.int64(blue) << 2 * bits)
        if with_color and not packed:
            for j in range(run):
                if cells[j] >= 0:
                    r, c = divmod(cells[j], cols)
                    b, i = block_of_row[r] + block_of_col[c], start + j
                    color[b, 0] += colors[i, 0]
                    color[b, 1] += colors[i, 1]
                    color[b, 2] += colors[i, 2]
        chunk_uv[chunk, 0], chunk_uv[chunk, 1] = u_min, u_max
        chunk_uv[chunk, 2], chunk_uv[chunk, 3] = v_min, v_max
    if by_cell:
        for r in range(rows):
            first = block_of_row[r]
            for c in range(cols):
                rgb[first + block_of_col[c]] += cell_rgb[r * cols + c]
    if packed:
        field = (1 << bits) - 1
        for b in range(rgb.shape[0]):
            color[b, 0] = rgb[b] & field
            color[b, 1] = (rgb[b] >> bits) & field
            color[b, 2] = rgb[b] >> 2 * bits
    return count, height, color, chunk_uv


@njit(cache=True, nogil=True)
def _block_counts(count: np.ndarray, shape: tuple[int, int], block: int) -> np.ndarray:
    """Points per block of ``block`` × ``block`` cells, from the (rows · cols) cell counts:
    one pass over the grid instead of a count per point."""
    rows, cols = shape
    block_cols = -(-cols // block)
    out = np.zeros(-(-rows // block) * block_cols, np.int32)
    for i in range(rows):
        row = count[i * cols : (i + 1) * cols]
        first = (i // block) * block_cols
        for b in range(block_cols):
            out[first + b] += row[b * block : (b + 1) * block].sum()
    return out


@njit(cache=True, nogil=True)
def _seam_bands(
    grid: np.ndarray, count: np.ndarray, lines: np.ndarray, sections: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols) int32: the seam whose band holds each cell, −1 none, −2 several; the
    ``TILE``-cell tiles holding band cells; and each seam's points in its band (an upper
    bound of those in its slabs). Only the cells that reach into one of the seam's slabs
    count (at the usual pitch and slab width, half of the band or less): the slab pass
    spends the least on a point whose cell is in no band."""
    rows, cols = count.shape
    seam_of_cell = np.full((rows, cols), -1, np.int32)
    band_tiles = np.zeros((-(-rows // TILE), -(-cols // TILE)), np.bool_)
    capacity = np.zeros(lines.shape[0], np.int64)
    cell = 1.0 / grid[2]
    for s in range(lines.shape[0]):
        cu, cv, du, dv = lines[s, 0], lines[s, 1], lines[s, 2], lines[s, 3]
        start, end = lines[s, 4], lines[s, 5]
        first, pitch = sections[s, 0], sections[s, 1]
        sections_count, half_slab = sections[s, 2], sections[s, 3]
        if sections_count < 1:
            continue
        wide = sections[s, 4] + cell  # the reach, and a cell
        # How far along the seam a cell's points lie from its centre, and a rounding's margin.
        cell_along = 0.5 * cell * (abs(du) + abs(dv)) + 1e-6
        # The band's bounding box: its four corners' cells.
        row0, row1, col0, col1 = rows, -1, cols, -1
        for along, across in (
            (start - 1, wide),
            (start - 1, -wide),
            (end + 1, wide),
            (end + 1, -wide),
        ):
            u, v = cu + along * du - across * dv, cv + along * dv + across * du
            row, col = (
                int(np.floor((u - grid[0]) * grid[2])),
                int(np.floor((v - grid[1]) * grid[2])),
            )
            row0, row1 = min(row0, row), max(row1, row)
            col0, col1 = min(col0, col), max(col1, col)
        for i in range(max(row0, 0), min(row1 + 1, rows)):
            for j in range(max(col0, 0), min(col1 + 1, cols)):
                du_c, dv_c = grid[0] + (i + 0.5) * cell - cu, grid[1] + (j + 0.5) * cell - cv
                along = du_c * du + dv_c * dv
                if abs(dv_c * du - du_c * dv) <= wide and start - 1 <= along <= end + 1:
                    # The sections whose slab the cell reaches (several where slabs overlap).
                    reach = half_slab + cell_along
                    k0 = max(np.ceil((along - reach - first) / pitch), 0.0)
                    k1 = min(np.floor((along + reach - first) / pitch), sections_count - 1)
                    if k1 < k0:
                        continue  # between two slabs
                    seam_of_cell[i, j] = s if seam_of_cell[i, j] == -1 else -2
                    band_tiles[i // TILE, j // TILE] = True
                    capacity[s] += count[i, j] * int(k1 - k0 + 1)
    return seam_of_cell, band_tiles, capacity


@njit(cache=True, nogil=True)
def _seam_slabs(
    points: np.ndarray,
    first_index: int,
    chunk_uv: np.ndarray,
    origin: np.ndarray,
    axes: np.ndarray,
    grid: np.ndarray,
    seam_of_cell: np.ndarray,
    band_tiles: np.ndarray,
    lines: np.ndarray,
    sections: np.ndarray,
    offsets: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(4, offsets[-1]) slab rows, seam s's from offsets[s]; and how many each seam has.
    ``points`` are the cloud's from its ``first_index``-th on (a point's index in the cloud
    decides whether a thinned slab keeps it)."""
    rows, cols = seam_of_cell.shape
    seams = lines.shape[0]
    flat = seam_of_cell.ravel()
    slab = np.empty((4, offsets[-1]))
    filled = np.zeros(seams, np.int64)
    t = _transform(origin, axes, grid)
    tile_scale = t[14] / TILE
    xyz, uvw = np.empty((3, CHUNK)), np.empty((3, CHUNK))
    cells = np.empty(CHUNK, np.int64)
    for chunk in range(-(-points.shape[0] // CHUNK)):
        # The tiles the run's box covers, give or take the box's float32 rounding (all of
        # the run if that is more than a few).
        box = chunk_uv[chunk]
        if box[0] > box[1]:
            continue  # no point of the run in the grid
        row0 = int(max((box[0] - t[12]) * tile_scale - 0.01, 0.0))
        row1 = int((box[1] - t[12]) * tile_scale + 0.01)
        col0 = int(max((box[2] - t[13]) * tile_scale - 0.01, 0.0))
        col1 = int((box[3] - t[13]) * tile_scale + 0.01)
        if (row1 - row0 + 1) * (col1 - col0 + 1) <= 16 and not band_tiles[
            row0 : row1 + 1, col0 : col1 + 1
        ].any():
            continue
        start = chunk * CHUNK
        run = min(points.shape[0], start + CHUNK) - start
        _locate(points, start, run, t, rows, cols, xyz, uvw, cells)
        for j in range(run):
            code = flat[cells[j]] if cells[j] >= 0 else -1
            if code == -1:
                continue
            u, v, w = uvw[0, j], uvw[1, j], uvw[2, j]
            # A cell in several bands (at junctions): try every seam; slabs lie in bands.
            low, high = (code, code + 1) if code >= 0 else (0, seams)
            for s in range(low, high):
                cu, cv, du, dv = lines[s, 0], lines[s, 1], lines[s, 2], lines[s, 3]
                first, pitch, count = sections[s, 0], sections[s, 1], sections[s, 2]
                half_slab, reach = sections[s, 3], sections[s, 4]
                dense_half, dense_reach = sections[s, 5], sections[s, 6]
                stride = int(sections[s, 7])
                along = (u - cu) * du + (v - cv) * dv
                across = (v - cv) * du - (u - cu) * dv
                if abs(across) >= reach:
                    continue
                thinned = abs(across) >= dense_reach and (first_index + start + j) % stride != 0
                # Every section whose slab holds the point: one, or several where the
                # slabs are wider than the pitch (a coarse cloud's sections, ``sections``).
                k0 = max(np.ceil((along - half_slab - first) / pitch), 0.0)
                k1 = min(np.floor((along + half_slab - first) / pitch), count - 1)
                k = k0
                while k <= k1:
                    y = along - (first + k * pitch)
                    if abs(y) <= half_slab and not (thinned and abs(y) > dense_half):
                        n = offsets[s] + filled[s]
                        slab[0, n], slab[1, n], slab[2, n], slab[3, n] = k, y, across, w
                        filled[s] += 1
                    k += 1.0
    return slab, filled
