"""The cloud seen as a height map: a surface frame fitted to the cloud and a grid of cells.

Panel assemblies are flat or gently curved, so seen along their mean normal they are a
height field. Everything that segments or searches works on this grid; what measures
goes back to the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SAMPLE_POINTS = 200_000


@dataclass(frozen=True)
class SurfaceFrame:
    """A frame on the cloud's best-fit plane: u along its longest extent, w along the mean
    normal towards the sensor. ``axes`` rows are u, v, w in the cloud's frame."""

    origin: np.ndarray
    axes: np.ndarray

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) cloud-frame points → (N, 3) float32 (u, v, w), mm."""
        return ((points - self.origin.astype(np.float32)) @ self.axes.T.astype(np.float32)).astype(
            np.float32
        )

    def to_cloud(self, local: np.ndarray) -> np.ndarray:
        """(…, 3) (u, v, w) → (…, 3) cloud-frame points, float64."""
        return np.asarray(local, dtype=np.float64) @ self.axes + self.origin

    def direction_to_cloud(self, local: np.ndarray) -> np.ndarray:
        return np.asarray(local, dtype=np.float64) @ self.axes


def fit_frame(
    points: np.ndarray, normals: np.ndarray | None, rng: np.random.Generator
) -> SurfaceFrame:
    """Principal axes of a sample of the points; w points where the normals do (or +z)."""
    sample = rng.choice(len(points), min(len(points), SAMPLE_POINTS), replace=False)
    chosen = points[sample].astype(np.float64)
    origin = chosen.mean(0)
    _, _, vt = np.linalg.svd(chosen - origin, full_matrices=False)
    towards = normals[sample].mean(0) if normals is not None else np.array([0.0, 0.0, 1.0])
    w = vt[2] if vt[2] @ towards >= 0 else -vt[2]
    u = vt[0]
    return SurfaceFrame(origin, np.stack([u, np.cross(w, u), w]))


@dataclass(frozen=True)
class Raster:
    """Cells of edge ``cell_mm`` over the (u, v) plane; cell (i, j) covers
    u ∈ origin_u + [i, i + 1)·cell, v likewise."""

    cell_mm: float
    origin_uv: np.ndarray
    height: np.ndarray
    """(rows, cols) float32 mean w of the points in each cell, NaN where none."""
    count: np.ndarray
    """(rows, cols) int32 points per cell."""
    cell_of_point: np.ndarray
    """(N,) int64 flat cell index of every point."""

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


def rasterize(local: np.ndarray, cell_mm: float) -> Raster:
    """Bin (N, 3) (u, v, w) points into cells of ``cell_mm``: mean height and count."""
    u, v = local[:, 0], local[:, 1]
    origin = np.array([float(u.min()) - cell_mm, float(v.min()) - cell_mm])
    scale = np.float32(1 / cell_mm)
    rows = ((u - np.float32(origin[0])) * scale).astype(np.int32)
    cols = ((v - np.float32(origin[1])) * scale).astype(np.int32)
    shape = (int(rows.max()) + 2, int(cols.max()) + 2)
    flat = rows.astype(np.int64) * shape[1] + cols
    count = np.bincount(flat, minlength=shape[0] * shape[1])
    total = np.bincount(flat, weights=local[:, 2], minlength=shape[0] * shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        height = (total / count).astype(np.float32)
    return Raster(
        cell_mm, origin, height.reshape(shape), count.reshape(shape).astype(np.int32), flat
    )


def point_spacing_mm(raster: Raster) -> float:
    """Typical distance between neighbouring points: √(covered area / points), the area
    counted in 1 mm blocks of the raster."""
    block = max(1, int(round(1.0 / raster.cell_mm)))
    rows, cols = raster.shape
    padded = np.zeros((-(-rows // block) * block, -(-cols // block) * block), np.int64)
    padded[:rows, :cols] = raster.count
    blocks = padded.reshape(padded.shape[0] // block, block, -1, block).sum(axis=(1, 3))
    area_mm2 = np.count_nonzero(blocks) * (block * raster.cell_mm) ** 2
    return float(np.sqrt(area_mm2 / max(int(raster.count.sum()), 1)))
