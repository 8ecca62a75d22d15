"""Clouds of two panels across one seam, made here without the project's simulator: a
height field sampled on a regular grid (an orthographic view from above), so the tests see
edges the simulator's sensor model never produced.

Panel a lies at x < −gap/2 with its top at z = 0, panel b at x > gap/2 with its top at
z = step; the seam runs along y; a backing lies 15 mm below. Each side's edge is
``("square", 0)``, ``("chamfer", width_mm)`` (45°), ``("round", radius_mm)`` or
``("rebate", width_mm)`` (a ledge that wide, 0.5 mm below the top, before the side face:
a profile none of vista's models describes). Faces steeper
than ``max_slope_deg`` return nothing, as a triangulation sensor's would.
"""

from __future__ import annotations

import numpy as np

from services.lib.pointcloud.ply import PointCloud


def _drop(kind: str, size: float, inside: np.ndarray) -> np.ndarray:
    """Depth below the top at ``inside`` mm from the side face (≥ 0)."""
    d = np.clip(size - inside, 0.0, size) if size else np.zeros_like(inside)
    if kind == "square":
        return np.zeros_like(inside)
    if kind == "chamfer":
        return d
    if kind == "round":
        return size - np.sqrt(np.maximum(size * size - d * d, 0.0))
    if kind == "rebate":
        return np.where(inside < size, 0.5, 0.0)
    raise ValueError(kind)


def _slope_deg(kind: str, size: float, inside: np.ndarray) -> np.ndarray:
    step = 1e-4
    rise = _drop(kind, size, inside - step) - _drop(kind, size, inside + step)
    return np.degrees(np.arctan(np.abs(rise) / (2 * step)))


def seam_cloud(
    gap_mm: float,
    step_mm: float,
    edge_a: tuple[str, float],
    edge_b: tuple[str, float],
    *,
    spacing_mm: float = 0.1,
    sigma_mm: float = 0.02,
    yaw_deg: float = 5.0,
    length_mm: float = 100.0,
    width_mm: float = 60.0,
    max_slope_deg: float = 75.0,
    seed: int = 0,
    taper_mm: float = 0.0,
) -> PointCloud:
    """The sampled cloud (float32, mm). The sampling grid is turned by ``yaw_deg`` against
    the seam, as a sensor's rows rarely run exactly along one. The gap widens by
    ``taper_mm`` along the seam, each edge leaving the seam's line by half of it."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(
        np.arange(-width_mm, width_mm, spacing_mm),
        np.arange(-width_mm, length_mm + width_mm, spacing_mm),
        indexing="ij",
    )
    angle = np.radians(yaw_deg)
    x = u * np.cos(angle) - v * np.sin(angle)
    y = u * np.sin(angle) + v * np.cos(angle)
    keep = (y > 0) & (y < length_mm) & (np.abs(x) < width_mm / 2)
    x, y = x[keep], y[keep]
    z = np.full(x.shape, -15.0)
    seen = np.ones(x.shape, bool)
    half_gap = (gap_mm + taper_mm * y / length_mm) / 2
    for side, (kind, size), top in ((-1, edge_a, 0.0), (1, edge_b, step_mm)):
        on = side * x > half_gap
        inside = side * x[on] - half_gap[on]
        z[on] = top - _drop(kind, size, inside)
        seen[on] = _slope_deg(kind, size, inside) < max_slope_deg
    z += rng.normal(0.0, sigma_mm, z.shape)
    points = np.stack([x, y, z], 1)[seen]
    return PointCloud(points=points.astype(np.float32))
