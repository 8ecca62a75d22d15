"""Panel segmentation on the height map: the flat tops, cut apart by seams."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from services.defects.morphology import erode
from services.defects.raster import Raster

FOUR_CONNECTED = ndimage.generate_binary_structure(2, 1)


@dataclass(frozen=True)
class Panels:
    labels: np.ndarray
    """(rows, cols) int32: 1…n the panel whose top a cell belongs to (its defects
    included), 0 = none (seams, rounded edges, backing, empty)."""
    count: int
    area_mm2: np.ndarray
    """(count,) top area of each panel."""


def segment_panels(
    raster: Raster,
    *,
    max_slope_deg: float,
    min_area_mm2: float,
    background_drop_mm: float,
) -> Panels:
    """Cells of a panel top are measured and flatter than ``max_slope_deg``; rounded
    edges and gaps are not, so they part the panels. The tops are eroded by one cell
    before labelling (4-connected) so a seam is never bridged diagonally, then grown back.
    Parts smaller than ``min_area_mm2`` are dropped, and so are parts lying more than
    ``background_drop_mm`` below the surface the panels make (the backing structure seen
    through gaps and around the assembly). Holes in a top (steep scratches and dents) are
    filled: they belong to the panel."""
    d_row, d_col = np.gradient(raster.height, raster.cell_mm)
    with np.errstate(invalid="ignore"):
        flat = d_row * d_row + d_col * d_col < np.tan(np.radians(max_slope_deg)) ** 2
    core = erode(flat, 1)
    labels, count = ndimage.label(core, structure=FOUR_CONNECTED)
    cell_area = raster.cell_mm**2
    sizes = np.bincount(labels.ravel(), minlength=count + 1)[1:] * cell_area
    keep = np.flatnonzero(sizes >= min_area_mm2) + 1
    keep = keep[~_below_surface(raster, labels, keep, background_drop_mm)]
    relabel = np.zeros(count + 1, dtype=np.int32)
    relabel[keep] = np.arange(1, len(keep) + 1)
    labels = relabel[labels]
    labels = np.where(flat, ndimage.maximum_filter(labels, size=3), 0).astype(np.int32)
    for label, found in enumerate(ndimage.find_objects(labels), start=1):
        holes = ndimage.binary_fill_holes(labels[found] == label) & (labels[found] == 0)
        labels[found][holes] = label
    area = np.bincount(labels.ravel(), minlength=len(keep) + 1)[1:] * cell_area
    return Panels(labels, len(keep), area)


def _below_surface(
    raster: Raster, labels: np.ndarray, candidates: np.ndarray, drop_mm: float
) -> np.ndarray:
    """(len(candidates),) bool: parts whose mean height lies more than ``drop_mm`` below a
    quadric fitted (trimmed, area-weighted) to all candidate parts."""
    stride = max(1, int(np.sqrt(labels.size / 50_000)))
    candidate = np.zeros(labels.max() + 1, bool)
    candidate[candidates] = True
    rows, cols = np.nonzero(candidate[labels[::stride, ::stride]])
    rows, cols = rows * stride, cols * stride
    uv = raster.centres_uv(rows, cols)
    u, v = uv[:, 0], uv[:, 1]
    design = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], 1)
    height = raster.height[rows, cols].astype(np.float64)
    inlier = np.ones(len(u), dtype=bool)
    for _ in range(5):
        coef, *_ = np.linalg.lstsq(design[inlier], height[inlier], rcond=None)
        inlier = np.abs(height - design @ coef) < drop_mm / 2
    residual = height - design @ coef
    part = labels[rows, cols]
    sums = np.bincount(part, weights=residual, minlength=labels.max() + 1)
    counts = np.bincount(part, minlength=labels.max() + 1)
    mean = sums[candidates] / np.maximum(counts[candidates], 1)
    return mean < -drop_mm
