"""What is in a scan: counts, bounds, spacing and density; and a decimated preview."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from services.lib.pointcloud.ply import PointCloud, read_ply
from services.scan.kinds import ScanInspectParams


@dataclass(frozen=True)
class ScanReport:
    point_count: int
    valid_point_count: int
    all_finite: bool
    organized: bool
    grid_width: int | None
    grid_height: int | None
    bounds_min_mm: tuple[float, float, float]
    bounds_max_mm: tuple[float, float, float]
    size_mm: tuple[float, float, float]
    mean_spacing_mm: float
    """Median distance from a point to its nearest neighbour."""
    density_per_mm2: float
    """Measured points per square millimetre of scanned surface."""
    surface_area_mm2: float


def _triple(values: np.ndarray) -> tuple[float, float, float]:
    return float(values[0]), float(values[1]), float(values[2])


def _grid_area_mm2(points: np.ndarray, grid_shape: tuple[int, int]) -> float:
    """Area of the triangulated grid over cells whose four corners were measured."""
    grid = points.reshape(grid_shape[0], grid_shape[1], 3).astype(np.float64)
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1], grid[1:, 1:]
    valid = np.isfinite(a).all(-1) & np.isfinite(b).all(-1) & np.isfinite(c).all(-1)
    valid &= np.isfinite(d).all(-1)
    first = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=-1)
    second = 0.5 * np.linalg.norm(np.cross(b - d, c - d), axis=-1)
    return float(np.sum((first + second)[valid]))


def nearest_spacing_mm(points: np.ndarray, *, sample: int, seed: int = 0) -> float:
    """Median nearest-neighbour distance of up to ``sample`` points of ``points`` (N, 3)."""
    if len(points) < 2:
        return 0.0
    rng = np.random.default_rng(seed)
    chosen = rng.choice(len(points), size=min(sample, len(points)), replace=False)
    distances, _ = cKDTree(points).query(points[chosen], k=2)
    return float(np.median(distances[:, 1]))


def inspect_cloud(cloud: PointCloud, *, spacing_sample: int = 20_000, seed: int = 0) -> ScanReport:
    """Summarise ``cloud`` (points (N, 3) float32, mm; NaN rows = unmeasured grid pixels)."""
    finite = np.isfinite(cloud.points).all(axis=1)
    valid = cloud.points[finite]
    if len(valid) == 0:
        raise ValueError("the cloud has no finite points")
    low, high = valid.min(axis=0).astype(np.float64), valid.max(axis=0).astype(np.float64)
    spacing = nearest_spacing_mm(valid, sample=spacing_sample, seed=seed)
    if cloud.grid_shape is not None:
        area = _grid_area_mm2(cloud.points, cloud.grid_shape)
    else:
        area = len(valid) * spacing**2
    return ScanReport(
        point_count=len(cloud.points),
        valid_point_count=int(finite.sum()),
        all_finite=bool(finite.all()),
        organized=cloud.grid_shape is not None,
        grid_width=cloud.grid_shape[1] if cloud.grid_shape else None,
        grid_height=cloud.grid_shape[0] if cloud.grid_shape else None,
        bounds_min_mm=_triple(low),
        bounds_max_mm=_triple(high),
        size_mm=_triple(high - low),
        mean_spacing_mm=spacing,
        density_per_mm2=float(len(valid) / area) if area > 0 else 0.0,
        surface_area_mm2=area,
    )


def _subset(cloud: PointCloud, index: np.ndarray) -> PointCloud:
    return PointCloud(
        points=cloud.points[index],
        normals=None if cloud.normals is None else cloud.normals[index],
        colors=None if cloud.colors is None else cloud.colors[index],
        intensity=None if cloud.intensity is None else cloud.intensity[index],
    )


def decimate(cloud: PointCloud, *, max_points: int, spacing_mm: float, seed: int = 0) -> PointCloud:
    """At most ``max_points`` points, one per voxel, voxel size grown until the budget fits.

    Unmeasured (NaN) points are dropped; the result is unorganized.
    """
    index = np.flatnonzero(np.isfinite(cloud.points).all(axis=1))
    points = cloud.points[index].astype(np.float64)
    if len(points) > max_points:
        voxel = max(spacing_mm, 1e-6) * np.sqrt(len(points) / max_points)
        low = points.min(axis=0)
        for _ in range(8):
            cells = np.floor((points - low) / voxel).astype(np.int64)
            dims = cells.max(axis=0) + 1
            keys = np.ravel_multi_index(cells.T, dims)
            _, first = np.unique(keys, return_index=True)
            if len(first) <= max_points:
                break
            voxel *= np.sqrt(len(first) / max_points) * 1.05
        else:
            rng = np.random.default_rng(seed)
            first = rng.choice(first, size=max_points, replace=False)
        index = index[np.sort(first)]
    return _subset(cloud, index)


@dataclass(frozen=True)
class ScanInspection:
    """One cloud checked: its report and its decimated preview."""

    report: ScanReport
    preview: PointCloud


def inspect_scan_file(path: Path, params: ScanInspectParams) -> ScanInspection:
    """The ``inspect`` verb: read the PLY at ``path``, report on it, decimate a preview.
    Raises ``PlyError`` for a file that is not a readable PLY and ``ValueError`` for a
    cloud without a finite point."""
    cloud = read_ply(path)
    report = inspect_cloud(cloud, spacing_sample=params.spacing_sample)
    preview = decimate(cloud, max_points=params.preview_points, spacing_mm=report.mean_spacing_mm)
    return ScanInspection(report, preview)
