"""Panel segmentation on the height map: the flat tops, cut apart by seams."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from services.defects.morphology import dilate, erode
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
    boxes: list[tuple[slice, slice]]
    """(count,) each panel's bounding box in the height map."""


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
    flat = _flat(raster.height, raster.cell_mm, max_slope_deg)
    core = erode(flat, 1)
    labels, count = ndimage.label(core, structure=FOUR_CONNECTED)
    cell_area = raster.cell_mm**2
    # Sizes from every 4th cell: plenty to tell a panel top from specks.
    sizes = np.bincount(labels[::2, ::2].ravel(), minlength=count + 1)[1:] * 4 * cell_area
    keep = np.flatnonzero(sizes >= min_area_mm2) + 1
    keep = keep[~_below_surface(raster, labels, keep, background_drop_mm)]
    relabel = np.zeros(count + 1, dtype=np.int32)
    relabel[keep] = np.arange(1, len(keep) + 1)
    labels = relabel[labels]
    labels = _grow(labels, flat)
    boxes = ndimage.find_objects(labels, len(keep))
    for label, found in enumerate(boxes, start=1):
        # Holes: parts of the rest of the panel's box that do not reach the box's border.
        rest, _ = ndimage.label(labels[found] != label)
        border = np.unique(np.concatenate([rest[0], rest[-1], rest[:, 0], rest[:, -1]]))
        reaches = np.zeros(rest.max() + 1, bool)
        reaches[border] = True
        labels[found][~reaches[rest] & (labels[found] == 0)] = label
    area = np.bincount(labels.ravel(), minlength=len(keep) + 1)[1:] * cell_area
    return Panels(labels, len(keep), area, boxes)


def _grow(labels: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Labels grown by one cell (the largest of the 3 × 3 neighbours) into the
    ``allowed`` cells without one; only that ring of cells is looked at."""
    ring = allowed & (labels == 0) & dilate(labels > 0, 1)
    ring[[0, -1], :] = ring[:, [0, -1]] = False  # every ring cell has 8 neighbours
    rows, cols = np.nonzero(ring)
    grown = labels.astype(np.int32)
    neighbours = [labels[rows + dr, cols + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)]
    grown[rows, cols] = np.max(neighbours, axis=0)
    return grown


def _flat(height: np.ndarray, cell_mm: float, max_slope_deg: float) -> np.ndarray:
    """Cells whose slope (central differences) is below ``max_slope_deg``; the border
    cells of the map are not."""
    d_row = (height[2:, 1:-1] - height[:-2, 1:-1]) / (2 * cell_mm)
    d_col = (height[1:-1, 2:] - height[1:-1, :-2]) / (2 * cell_mm)
    flat = np.zeros(height.shape, bool)
    with np.errstate(invalid="ignore"):
        flat[1:-1, 1:-1] = d_row * d_row + d_col * d_col < np.tan(np.radians(max_slope_deg)) ** 2
    return flat


def _below_surface(
    raster: Raster, labels: np.ndarray, candidates: np.ndarray, drop_mm: float
) -> np.ndarray:
    """(len(candidates),) bool: parts whose mean height lies more than ``drop_mm`` below a
    quadric fitted (trimmed, area-weighted) to all candidate parts."""
    stride = max(1, int(np.sqrt(labels.size / 20_000)))
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
        chosen = design[inlier]
        coef = np.linalg.lstsq(chosen.T @ chosen, chosen.T @ height[inlier], rcond=None)[0]
        inlier = np.abs(height - design @ coef) < drop_mm / 2
    residual = height - design @ coef
    part = labels[rows, cols]
    sums = np.bincount(part, weights=residual, minlength=labels.max() + 1)
    counts = np.bincount(part, minlength=labels.max() + 1)
    mean = sums[candidates] / np.maximum(counts[candidates], 1)
    return mean < -drop_mm
