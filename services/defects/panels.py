"""Panel segmentation on the height map: the flat tops, cut apart by seams."""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage

from services.defects.morphology import border_reach, label4
from services.defects.raster import Raster
from services.lib.tasks import helping_map


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
    bridge_cells: int = 0,
    pool: Executor | None = None,
    helpers: int = 0,
) -> Panels:
    """Cells of a panel top are measured and flatter than ``max_slope_deg``; rounded
    edges and gaps are not, so they part the panels. The tops are eroded by one cell
    before labelling (4-connected) so a seam is never bridged diagonally, then grown back;
    and by ``bridge_cells`` more where a coarse scan leaves a gap unseen over stretches
    of a few cells (its rows skip a gap narrower than their spacing): the stretches no
    longer join two panels, which then grow back towards each other.
    Parts smaller than ``min_area_mm2`` are dropped, and so are parts lying more than
    ``background_drop_mm`` below the surface the panels make (the backing structure seen
    through gaps and around the assembly). Holes in a top (steep scratches and dents) are
    filled: they belong to the panel. On such a coarse map the cells beside a step between
    two tops (``_steps``) part them too: a gap its rows skip leaves no slope to see there,
    where a cell is as wide as the step is high. The passes after the labelling run on
    this thread and up to ``helpers`` of ``pool``'s."""
    height = _filled_pinholes(raster.height)
    flat, core = _flat_core(height, 2 * raster.cell_mm * np.tan(np.radians(max_slope_deg)))
    if bridge_cells:
        steps = _steps(height, flat, STEP_MM)
        flat &= ~steps
        core = ndimage.binary_erosion(core, iterations=bridge_cells)
        core &= ~ndimage.binary_dilation(steps, iterations=STEP_REACH_CELLS)
    labels, sizes = label4(core)
    count = len(sizes)
    cell_area = raster.cell_mm**2
    # a square panel of the least area keeps this much of it through the extra erosion
    side = max(np.sqrt(min_area_mm2) - 2 * bridge_cells * raster.cell_mm, raster.cell_mm)
    keep = np.flatnonzero(sizes * cell_area >= min(min_area_mm2, side**2)) + 1
    keep = keep[~_below_surface(raster, height, labels, count, keep, background_drop_mm)]
    relabel = np.zeros(count + 1, dtype=np.int32)
    relabel[keep] = np.arange(1, len(keep) + 1)
    labels, corners, cells = _grown(labels, relabel, flat, len(keep), pool, helpers)
    same = np.arange(len(keep) + 1, dtype=np.int32)
    for _ in range(bridge_cells):  # back to the flat cells the erosion took
        labels, corners, cells = _grown(labels, same, flat, len(keep), pool, helpers)
    boxes = [(slice(r0, r1 + 1), slice(c0, c1 + 1)) for r0, c0, r1, c1 in corners]

    # Holes: cells of no panel that the rest of the panel's box does not join to the box's
    # border. What each box encloses is found for all panels at once: filling one panel's
    # holes turns cells of no panel into cells of another panel, which its neighbour's
    # box encloses no more or less than before.
    def enclosed(label: int, box: tuple[slice, slice]) -> np.ndarray:
        return ~border_reach(labels[box] != label)

    inner = helping_map(pool, enclosed, range(1, len(boxes) + 1), boxes, helpers=helpers)
    for label, (found, enclosed_cells) in enumerate(zip(boxes, inner, strict=True), start=1):
        box = labels[found]
        hole = enclosed_cells & (box == 0)
        box[hole] = label
        cells[label - 1] += np.count_nonzero(hole)
    return Panels(labels, len(keep), cells * cell_area, boxes)


PINHOLE_NEIGHBOURS = 7
"""An empty cell with at least this many of its 8 neighbours measured is a pinhole."""


@njit(cache=True, nogil=True)
def _filled_pinholes(height: np.ndarray) -> np.ndarray:
    """``height`` with each pinhole (an empty cell, NaN, with ``PINHOLE_NEIGHBOURS`` or
    more of its 8 neighbours measured) given its measured neighbours' mean. A scan grid
    turned to the map's cells leaves such cells empty in a pattern (moiré) once the cell
    is not much larger than the point spacing; each would stop the flat tops around it
    (a cell next to an empty one is not flat) and cut a panel into pieces. A gap's empty
    cells lie in lines, whose cells have at most 6 measured neighbours (where the gap is
    one cell wide): they stay empty, and the panels apart."""
    rows, cols = height.shape
    out = height.copy()
    for i in range(1, rows - 1):
        for j in range(1, cols - 1):
            if np.isfinite(height[i, j]):
                continue
            total, seen = 0.0, 0
            for di in range(-1, 2):
                for dj in range(-1, 2):
                    value = height[i + di, j + dj]
                    if np.isfinite(value):
                        total += value
                        seen += 1
            if seen >= PINHOLE_NEIGHBOURS:
                out[i, j] = total / seen
    return out


STEP_MM = 0.2
"""On a coarse map (``bridge_cells``), two cells lie beside a step where the tops either
side of them, three cells each way, are offset by more than this beyond their slope."""


STEP_REACH_CELLS = 2
"""The cells at a step part the tops' cores this many cells either side (closing breaks of
up to twice this along the step): not the whole extra erosion's 6, since the step rule
also fires on a dent's or a bump's floor and walls, in ones and twos or in a ring, and
each cell marked then took a disc 13 cells across out of the top — one beside a gap took
the top's edge from it over 20 mm, which the growth back could not restore."""


@njit(cache=True, nogil=True)
def _steps(height: np.ndarray, flat: np.ndarray, min_step_mm: float) -> np.ndarray:
    """(rows, cols) bool: the two cells either side of each step along a row or a column
    of ``flat`` cells — between cells i and i + 1, the mean height of cells i + 1…i + 3
    less that of i − 2…i, less the slope either side (the means of i + 4…i + 6 and of
    i − 5…i − 3, averaged), beyond ``min_step_mm`` and no less than within three cells
    of it (a step shifts the windows one and three cells beside it by half as much), where
    all twelve are flat (a gap seen, an edge or the backing is no step). A plane gives 0
    and a step its height; a groove one cell wide half its depth."""
    rows, cols = height.shape
    out = np.zeros((rows, cols), np.bool_)
    m = np.zeros(4)  # means of i−5…i−3, i−2…i, i+1…i+3, i+4…i+6
    for axis in range(2):
        length, other = (rows, cols) if axis == 0 else (cols, rows)
        step = np.zeros(length)
        for k in range(other):
            step[:] = 0.0
            for i in range(5, length - 6):
                m[:] = 0.0
                level = True
                for part in range(4):
                    for t in range(3):
                        at = i - 5 + 3 * part + t
                        level &= flat[at, k] if axis == 0 else flat[k, at]
                        m[part] += height[at, k] if axis == 0 else height[k, at]
                if level:
                    m /= 3.0
                    step[i] = abs((m[2] - m[1]) - ((m[3] - m[2]) + (m[1] - m[0])) / 2)
            for i in range(5, length - 6):
                if step[i] > min_step_mm and step[i] >= step[i - 3 : i + 4].max():
                    if axis == 0:
                        out[i, k] = out[i + 1, k] = True
                    else:
                        out[k, i] = out[k, i + 1] = True
    return out


@njit(cache=True, nogil=True)
def _flat_core(height: np.ndarray, max_rise_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(flat, core): cells whose slope (central differences) rises less than
    ``max_rise_mm`` over two cells — the map's border cells and cells next to an empty
    one are not flat — and the flat cells whose 3 × 3 neighbours are all flat."""
    rows, cols = height.shape
    limit = max_rise_mm * max_rise_mm
    flat = np.zeros((rows, cols), np.bool_)
    for i in range(1, rows - 1):
        for j in range(1, cols - 1):
            d_row = np.float64(height[i + 1, j]) - height[i - 1, j]
            d_col = np.float64(height[i, j + 1]) - height[i, j - 1]
            flat[i, j] = d_row * d_row + d_col * d_col < limit  # NaN: not flat
    across = np.zeros((rows, cols), np.bool_)  # flat with both neighbours along the row
    for i in range(rows):
        for j in range(1, cols - 1):
            across[i, j] = flat[i, j - 1] and flat[i, j] and flat[i, j + 1]
    core = np.zeros((rows, cols), np.bool_)
    for i in range(1, rows - 1):
        for j in range(cols):
            core[i, j] = across[i - 1, j] and across[i, j] and across[i + 1, j]
    return flat, core


def _grown(
    labels: np.ndarray,
    relabel: np.ndarray,
    flat: np.ndarray,
    count: int,
    pool: Executor | None,
    helpers: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_relabel_grow`` on bands of rows, on this thread and up to ``helpers`` of
    ``pool``'s: the (rows, cols) grown labels, and each label's box and cells."""
    rows = labels.shape[0]
    grown = np.empty(labels.shape, np.int32)
    bands = helpers + 1
    edges = [rows * k // bands for k in range(bands + 1)]
    parts = helping_map(
        pool,
        lambda first, last: _relabel_grow(labels, relabel, flat, count, grown, first, last),
        edges[:-1],
        edges[1:],
        helpers=helpers,
    )
    corners = np.concatenate(
        [
            np.min([part[0][:, :2] for part in parts], axis=0),
            np.max([part[0][:, 2:] for part in parts], axis=0),
        ],
        axis=1,
    )
    return grown, corners, np.sum([part[1] for part in parts], axis=0)


@njit(cache=True, nogil=True)
def _relabel_grow(
    labels: np.ndarray,
    relabel: np.ndarray,
    flat: np.ndarray,
    count: int,
    grown: np.ndarray,
    first_row: int,
    last_row: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``first_row`` to ``last_row`` (exclusive) of ``grown``: the parts renamed by
    ``relabel`` and grown by one cell (the largest of the 3 × 3 neighbours) into the
    ``flat`` cells without one (not on the map's border); with each of the ``count``
    labels' (row0, col0, row1, col1) inclusive box in those rows (row0 > row1 if none)
    and its cells there."""
    rows, cols = labels.shape
    corners = np.empty((count, 4), np.int64)
    corners[:, :2] = max(rows, cols)
    corners[:, 2:] = -1
    cells = np.zeros(count, np.int64)
    for i in range(first_row, last_row):
        run_label, run_start = 0, 0  # the boxes and counts grow by runs along the row
        for j in range(cols + 1):
            label = 0
            if j < cols:
                label = relabel[labels[i, j]]
                if label == 0 and flat[i, j] and 0 < i < rows - 1 and 0 < j < cols - 1:
                    for di in range(-1, 2):
                        for dj in range(-1, 2):
                            label = max(label, relabel[labels[i + di, j + dj]])
                grown[i, j] = label
            if label != run_label or j == cols:
                if run_label > 0:
                    box = corners[run_label - 1]
                    box[0], box[1] = min(box[0], i), min(box[1], run_start)
                    box[2], box[3] = max(box[2], i), max(box[3], j - 1)
                    cells[run_label - 1] += j - run_start
                run_label, run_start = label, j
    return corners, cells


def _below_surface(
    raster: Raster,
    height_mm: np.ndarray,
    labels: np.ndarray,
    count: int,
    candidates: np.ndarray,
    drop_mm: float,
) -> np.ndarray:
    """(len(candidates),) bool: of the ``count`` parts ``labels`` numbers, those among
    ``candidates`` whose mean height lies more than ``drop_mm`` below a quadric fitted
    (trimmed, area-weighted) to the candidate parts; ``height_mm`` is the map's, its
    pinholes filled."""
    stride = max(1, int(np.sqrt(labels.size / 20_000)))
    candidate = np.zeros(count + 1, bool)
    candidate[candidates] = True
    rows, cols = np.nonzero(candidate[labels[::stride, ::stride]])
    rows, cols = rows * stride, cols * stride
    uv = raster.centres_uv(rows, cols)
    u, v = uv[:, 0], uv[:, 1]
    design = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], 1)
    height = height_mm[rows, cols].astype(np.float64)
    # Started from the parts not far below the median height: a backing seen around an
    # assembly turned in its scans can be a large part, and a quadric through it bends.
    inlier = height >= np.median(height) - drop_mm
    for _ in range(5):
        chosen = design[inlier]
        coef = np.linalg.lstsq(chosen.T @ chosen, chosen.T @ height[inlier], rcond=None)[0]
        inlier = np.abs(height - design @ coef) < drop_mm / 2
    residual = height - design @ coef
    part = labels[rows, cols]
    sums = np.bincount(part, weights=residual, minlength=count + 1)
    counts = np.bincount(part, minlength=count + 1)
    mean = sums[candidates] / np.maximum(counts[candidates], 1)
    return mean < -drop_mm


@dataclass(frozen=True)
class PanelShape:
    """Where a panel is, in the surface frame (u, v, w; mm)."""

    label: int
    centroid: np.ndarray
    """(3,) the centre of its top."""
    normal: np.ndarray
    """(3,) unit normal of the plane fitted to its top, towards +w."""
    outline: np.ndarray
    """(P, 3) its top's outline, a closed polygon (first point not repeated)."""
    area_mm2: float


def describe_panels(
    raster: Raster, panels: Panels, *, tolerance_mm: float = 0.5
) -> list[PanelShape]:
    """Centroid, plane normal and outline (simplified to ``tolerance_mm``) of every panel's
    top, from the height map's cells every ``tolerance_mm`` or so."""
    import cv2

    step = max(1, int(tolerance_mm / raster.cell_mm))
    shapes = []
    for label, (rows, cols) in enumerate(panels.boxes, start=1):
        mask = panels.labels[rows, cols][::step, ::step] == label
        r, c = np.nonzero(mask)
        thin = max(1, len(r) // 4_000)  # enough cells for a plane
        r, c = r[::thin] * step + rows.start, c[::thin] * step + cols.start
        heights = raster.height[r, c].astype(np.float64)
        uv = raster.centres_uv(r, c)
        known = np.isfinite(heights)
        centre_uv = uv.mean(axis=0)
        design = np.column_stack([np.ones(known.sum()), uv[known] - centre_uv])
        (w0, du, dv), *_ = np.linalg.lstsq(design, heights[known], rcond=None)
        normal = np.array([-du, -dv, 1.0]) / np.linalg.norm([-du, -dv, 1.0])
        contours, _ = cv2.findContours(
            mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE
        )
        outer = max(contours, key=cv2.contourArea)
        polygon = cv2.approxPolyDP(outer, tolerance_mm / (step * raster.cell_mm), True)[:, 0, :]
        outline_uv = raster.centres_uv(
            polygon[:, 1] * step + rows.start, polygon[:, 0] * step + cols.start
        )
        outline_w = w0 + (outline_uv - centre_uv) @ np.array([du, dv])
        shapes.append(
            PanelShape(
                label,
                np.array([*centre_uv, w0]),
                normal,
                np.column_stack([outline_uv, outline_w]),
                float(panels.area_mm2[label - 1]),
            )
        )
    return shapes
