"""Clean-up of stitched scans: outliers by Local Outlier Probabilities, closest vertices
merged, isolated remains filtered. All vectorised; organized scans use their grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import erf

from services.lib.pointcloud.grid import shifted, window_offsets

KEY_BITS = 21
"""Voxel index bits per axis: 2²¹ voxels of 0.1 mm span 210 m, far beyond any cell."""


def loop_probability(
    pdist: np.ndarray, expected: np.ndarray, lam: float, *, scale: np.ndarray | None = None
) -> np.ndarray:
    """LoOP from each point's probabilistic distance and its context's mean one:
    ``PLOF = pdist / expected − 1``; ``LoOP = max(0, erf(PLOF / (λ·sqrt(mean PLOF²)·√2)))``,
    the mean over ``scale`` (PLOFs from which to take it) if given, else over these.
    NaN in, NaN out (the normalisation uses the finite values only)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        plof = pdist / expected - 1.0
    reference = plof if scale is None else scale
    finite = np.isfinite(reference)
    nplof = lam * np.sqrt(np.mean(reference[finite] ** 2)) if finite.any() else 0.0
    probability = np.full(plof.shape, np.nan, dtype=np.float32)
    known = np.isfinite(plof)
    probability[known] = (
        np.maximum(0.0, erf(plof[known] / (nplof * np.sqrt(2)))) if nplof > 0 else 0.0
    )
    return probability


JUMP_SPACINGS = 3.0
"""A grid neighbour farther than this many typical neighbour distances lies across a depth
jump (an edge over a gap, a step): it is not part of the pixel's own context."""


def _grid_plof(
    squared: np.ndarray, present: np.ndarray, offsets: list, lam: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pdist, mean pdist of the context, support) over the ``present`` neighbours."""
    support = present.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        pdist = lam * np.sqrt(np.where(present, squared, 0.0).sum(axis=0) / support)
        neighbour_pdist = np.stack([shifted(pdist[..., None], r, c)[..., 0] for r, c in offsets])
        usable = present & np.isfinite(neighbour_pdist)
        expected = np.where(usable, neighbour_pdist, 0.0).sum(axis=0) / usable.sum(axis=0)
    return pdist, expected, support


def loop_grid(grid: np.ndarray, *, radius_px: int = 1, lam: float = 3.0) -> np.ndarray:
    """Local Outlier Probability (Kriegel et al. 2009) of every pixel of an organized scan.

    The context set of a pixel is its measured neighbours in a (2r+1)² window.
    ``pdist = λ·sqrt(mean d²)``; ``PLOF = pdist / mean(neighbours' pdist) − 1``;
    ``LoOP = max(0, erf(PLOF / (λ·sqrt(mean PLOF²)·√2)))``.

    A pixel's own PLOF leaves out the neighbours across a depth jump (farther than
    ``JUMP_SPACINGS`` × the scan's median distance to a nearest neighbour), as a 3-D
    nearest-neighbour context would: with them, the last pixel of a panel's top before a
    gap was judged by the floor far below, looked like an outlier and was removed, which
    moved the edge by a point spacing. The normalisation (mean PLOF²) is still taken over
    the whole windows, so how sure LoOP is elsewhere — a scratch's groove is not an
    outlier — is unchanged.

    grid : (rows, columns, 3) float32, mm, NaN = not measured.
    Returns (rows, columns) float32 in [0, 1]; NaN where unmeasured; 1 where a pixel has
    fewer than two measured neighbours on its side of any jump (nothing supports it).
    """
    offsets = window_offsets(radius_px)
    squared = np.stack([np.sum((shifted(grid, r, c) - grid) ** 2, axis=-1) for r, c in offsets])
    measured_pairs = np.isfinite(squared)
    with np.errstate(invalid="ignore", divide="ignore"):
        nearest = np.min(np.where(measured_pairs, squared, np.inf), axis=0)
        finite = np.isfinite(nearest)
        typical = np.median(nearest[finite]) if finite.any() else 0.0
        whole = _grid_plof(squared, measured_pairs, offsets, lam)
        scale = whole[0] / whole[1] - 1.0
    present = (
        measured_pairs & (squared <= JUMP_SPACINGS**2 * typical) if typical > 0 else measured_pairs
    )
    pdist, expected, support = _grid_plof(squared, present, offsets, lam)
    probability = loop_probability(pdist, expected, lam, scale=scale)
    measured = np.isfinite(grid).all(axis=-1)
    probability[measured & (support < 2)] = 1.0
    return probability


def loop_unorganized(points: np.ndarray, *, neighbours: int = 8, lam: float = 3.0) -> np.ndarray:
    """LoOP of an unorganized (N, 3) cloud over its k nearest neighbours."""
    distances, index = cKDTree(points).query(points, k=neighbours + 1, workers=-1)
    pdist = lam * np.sqrt(np.mean(distances[:, 1:] ** 2, axis=1))
    return loop_probability(pdist, np.mean(pdist[index[:, 1:]], axis=1), lam)


def voxel_keys(points: np.ndarray, voxel_mm: float) -> np.ndarray:
    """(N,) int64 key of each point's voxel (edge ``voxel_mm``), unique per voxel."""
    index = np.floor(points / voxel_mm).astype(np.int64) + (1 << (KEY_BITS - 1))
    if index.min() < 0 or index.max() >= 1 << KEY_BITS:
        raise ValueError(f"the cloud spans more than {(1 << KEY_BITS) * voxel_mm / 1000:.0f} m")
    return (index[:, 0] << (2 * KEY_BITS)) | (index[:, 1] << KEY_BITS) | index[:, 2]


@dataclass(frozen=True)
class Merged:
    points: np.ndarray
    """(M, 3) float32, mm: mean of the points merged into each voxel."""
    normals: np.ndarray | None
    """(M, 3) float32 unit mean normals."""
    intensity: np.ndarray | None
    colors: np.ndarray | None
    """(M, 3) uint8 mean colour."""
    support: np.ndarray
    """(M,) int32 points merged into each."""


def voxel_merge(
    points: np.ndarray,
    voxel_mm: float,
    *,
    normals: np.ndarray | None = None,
    intensity: np.ndarray | None = None,
    colors: np.ndarray | None = None,
) -> Merged:
    """Merge the points falling into one voxel into their mean (normals renormalised,
    colours rounded)."""
    keys = voxel_keys(points, voxel_mm)
    unique, inverse, support = np.unique(keys, return_inverse=True, return_counts=True)

    def mean(values: np.ndarray) -> np.ndarray:
        columns = [np.bincount(inverse, weights=values[:, i]) for i in range(values.shape[1])]
        return np.stack(columns, 1) / support[:, None]

    merged_normals = None
    if normals is not None:
        merged_normals = mean(normals)
        merged_normals /= np.maximum(np.linalg.norm(merged_normals, axis=1, keepdims=True), 1e-12)
        merged_normals = merged_normals.astype(np.float32)
    merged_intensity = None
    if intensity is not None:
        merged_intensity = mean(intensity[:, None])[:, 0].astype(np.float32)
    merged_colors = None
    if colors is not None:
        merged_colors = np.rint(mean(colors.astype(np.float64))).astype(np.uint8)
    return Merged(
        mean(points).astype(np.float32),
        merged_normals,
        merged_intensity,
        merged_colors,
        support.astype(np.int32),
    )


def isolated_points(points: np.ndarray, *, cell_mm: float, min_points: int) -> np.ndarray:
    """(N,) bool: points whose cell (edge ``cell_mm``) and its 26 neighbours hold fewer than
    ``min_points`` points in all: what is left of spray and stray returns after merging."""
    keys = voxel_keys(points, cell_mm)
    cells, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    mask = (1 << KEY_BITS) - 1
    index = np.stack(
        [(cells >> (2 * KEY_BITS)) & mask, (cells >> KEY_BITS) & mask, cells & mask], 1
    )
    around = np.zeros(len(cells), dtype=np.int64)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                moved = index + (dx, dy, dz)
                probe = (moved[:, 0] << (2 * KEY_BITS)) | (moved[:, 1] << KEY_BITS) | moved[:, 2]
                slot = np.minimum(np.searchsorted(cells, probe), len(cells) - 1)
                around += np.where(cells[slot] == probe, counts[slot], 0)
    return around[inverse] < min_points
