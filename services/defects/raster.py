"""The cloud seen as a height map: a surface frame fitted to the cloud and a grid of cells.

Panel assemblies are flat or gently curved, so seen along their mean normal they are a
height field. Everything that segments or searches works on this grid; what measures
goes back to the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.defects import binning

SAMPLE_POINTS = 50_000
BOUNDS_MARGIN_MM = 3.0
"""The height map reaches this far beyond the extent of the points' sample."""
BLOCK_MM = 1.0
"""Coarse work (colour, the reference surface, point spacing) is done on blocks of cells
about this size."""


def block_cells(cell_mm: float) -> int:
    """Cells along the side of a block."""
    return max(1, int(round(BLOCK_MM / cell_mm)))


def block_sums(values: np.ndarray, block: int) -> np.ndarray:
    """Sums over ``block`` × ``block`` cells of a (rows, cols, …) array (zero-padded to
    whole blocks; booleans are counted)."""
    rows, cols = values.shape[:2]
    shape = (-(-rows // block), -(-cols // block))
    dtype = np.int32 if values.dtype == bool else values.dtype
    padded = np.zeros((shape[0] * block, shape[1] * block, *values.shape[2:]), dtype)
    padded[:rows, :cols] = values
    # Strided adds: several times faster than summing a reshaped array's inner axes.
    across = padded[:, 0::block].copy()
    for i in range(1, block):
        across += padded[:, i::block]
    sums = across[0::block].copy()
    for i in range(1, block):
        sums += across[i::block]
    return sums


@dataclass(frozen=True)
class SurfaceFrame:
    """A frame on the cloud's best-fit plane: u along its longest extent, w along the mean
    normal towards the sensor. ``axes`` rows are u, v, w in the cloud's frame."""

    origin: np.ndarray
    axes: np.ndarray

    def to_cloud(self, local: np.ndarray) -> np.ndarray:
        """(…, 3) (u, v, w) → (…, 3) cloud-frame points, float64."""
        return np.asarray(local, dtype=np.float64) @ self.axes + self.origin

    def direction_to_cloud(self, local: np.ndarray) -> np.ndarray:
        return np.asarray(local, dtype=np.float64) @ self.axes

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """(…, 3) cloud-frame points → (…, 3) (u, v, w), float64."""
        return (np.asarray(points, dtype=np.float64) - self.origin) @ self.axes.T


def fit_frame(points: np.ndarray, normals: np.ndarray | None) -> SurfaceFrame:
    """Principal axes of an even sample of the finite points (every k-th: the scans'
    order spreads it over the whole cloud); w points where the normals do (or +z)."""
    step = max(1, len(points) // SAMPLE_POINTS)
    count, origin, covariance, towards = binning.sample_moments(points, normals, step)
    if count < 3:
        return SurfaceFrame(np.zeros(3), np.eye(3))
    _, vectors = np.linalg.eigh(covariance)
    if not towards.any():  # no (finite) normals
        towards = np.array([0.0, 0.0, 1.0])
    w = vectors[:, 0] if vectors[:, 0] @ towards >= 0 else -vectors[:, 0]
    u = vectors[:, 2]
    return SurfaceFrame(origin, np.stack([u, np.cross(w, u), w]))


@dataclass(frozen=True)
class Raster:
    """Cells of edge ``cell_mm`` over the (u, v) plane of ``frame``; cell (i, j) covers
    u ∈ origin_u + [i, i + 1)·cell, v likewise."""

    frame: SurfaceFrame
    cell_mm: float
    origin_uv: np.ndarray
    height: np.ndarray
    """(rows, cols) float32 mean w of the points in each cell, NaN where none."""
    count: np.ndarray
    """(rows, cols) int32 points per cell."""
    block_count: np.ndarray
    """(⌈rows / b⌉, ⌈cols / b⌉) int32 points per block of b = ``block_cells(cell_mm)``
    cells square."""
    block_rgb: np.ndarray | None
    """(⌈rows / b⌉, ⌈cols / b⌉, 3) float32 mean sRGB colour of the points in each block
    (NaN where none), if the cloud has colours."""
    chunk_uv: np.ndarray
    """(⌈N / binning.CHUNK⌉, 4) float32 (u_min, u_max, v_min, v_max) of each run of
    ``binning.CHUNK`` consecutive points of the binned cloud (min > max if none is in the
    grid): where later passes over the same points may look."""

    @property
    def shape(self) -> tuple[int, int]:
        return self.height.shape

    def centres_uv(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(…, 2) (u, v) of cell centres."""
        return self.origin_uv + (np.stack([rows, cols], -1) + 0.5) * self.cell_mm

    def cell_at(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, inside) of the cells holding (…, 2) (u, v) points."""
        index = np.floor((uv - self.origin_uv) / self.cell_mm).astype(np.int64)
        rows, cols = index[..., 0], index[..., 1]
        inside = (rows >= 0) & (rows < self.shape[0]) & (cols >= 0) & (cols < self.shape[1])
        return np.clip(rows, 0, self.shape[0] - 1), np.clip(cols, 0, self.shape[1] - 1), inside

    @property
    def grid(self) -> np.ndarray:
        """(u0, v0, 1 / cell) for the compiled passes."""
        return np.array([self.origin_uv[0], self.origin_uv[1], 1 / self.cell_mm])


def rasterize(
    points: np.ndarray,
    colors: np.ndarray | None,
    frame: SurfaceFrame,
    cell_mm: float,
    bounds_uv: np.ndarray,
    workers: int = 1,
) -> Raster:
    """Bin (N, 3) cloud-frame points (and their (N, 3) uint8 colours) into cells of
    ``cell_mm`` on ``frame``: count and mean height per cell, mean colour per block. The
    grid covers ``bounds_uv`` (u_min, u_max, v_min, v_max of a sample, from
    ``binning.uv_bounds``) and ``BOUNDS_MARGIN_MM`` around; points beyond it (strays) and
    points that are not finite are left out. ``workers``: threads for the pass."""
    margin = BOUNDS_MARGIN_MM + cell_mm
    origin = np.array([bounds_uv[0] - margin, bounds_uv[2] - margin])
    shape = (
        int((bounds_uv[1] + margin - origin[0]) / cell_mm) + 1,
        int((bounds_uv[3] + margin - origin[1]) / cell_mm) + 1,
    )
    grid = np.array([origin[0], origin[1], 1 / cell_mm])
    block = block_cells(cell_mm)
    count, total, block_count, color_total, chunk_uv = binning.bin_points(
        points, colors, frame.origin, frame.axes, grid, shape, block, workers
    )
    count = count.reshape(shape)
    block_count = block_count.reshape(-(-shape[0] // block), -(-shape[1] // block))
    with np.errstate(invalid="ignore", divide="ignore"):
        height = np.divide(total.reshape(shape), count, dtype=np.float32)
        block_rgb = None
        if color_total is not None:
            rgb = color_total.reshape(*block_count.shape, 3) / block_count[..., None]
            block_rgb = rgb.astype(np.float32)
    return Raster(frame, cell_mm, origin, height, count, block_count, block_rgb, chunk_uv)


def point_spacing_mm(raster: Raster) -> float:
    """Typical distance between neighbouring points: √(covered area / points), the area
    counted in blocks of the raster."""
    block_mm = block_cells(raster.cell_mm) * raster.cell_mm
    area_mm2 = np.count_nonzero(raster.block_count) * block_mm**2
    return float(np.sqrt(area_mm2 / max(int(raster.block_count.sum()), 1)))
