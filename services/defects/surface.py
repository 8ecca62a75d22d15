"""Surface defects on each panel top: dents and bumps, scratches, colour patches.

- **Reference surface.** Per panel, on 1 mm blocks of the height map: a cubic polynomial
  in (u, v) fitted with Tukey weights, plus a normalised Gaussian smoothing (σ =
  ``smooth_mm``) of the inlier residual, so gentle waviness is followed but a dent is not.
- **Dents and bumps.** Blocks deviating from the reference by more than
  ``dent_detect_mm`` form regions; depth = the largest deviation of the 3 × 3-averaged
  height map inside (signed: below = dent), diameter = that of the circle with the
  region's area where the deviation exceeds a quarter of the depth.
- **Scratches.** A band-pass of the fine height map (Gaussian σ = one cell minus σ =
  ``scratch_background_mm``, the latter taken on the blocks) in units of its robust
  noise level; depressions beyond ``scratch_sigma`` (hysteresis from ``scratch_sigma`` +
  2) that are long and thin (length ≥ ``scratch_min_length_mm``, length / width ≥ 4)
  and at least ``scratch_min_depth_mm`` deep, and not within ``relief_rim_mm`` of a dent
  or bump at least twice that across (whose foot curves like a groove), are scratches.
  Length from the region's principal axes; depth = the 98th percentile of the cells'
  depth below the smoothed surface (a lower bound for scratches narrower than a cell);
  width = 1.5 × the mean section area / depth (exact for a parabolic groove).
- **Colour.** Mean colour on 1 mm blocks in CIE L*a*b*; the panel's own colour is the
  normalised Gaussian average (σ = ``smooth_mm``) of the blocks within ``color_detect``
  ΔE of its median; blocks further than ``color_detect`` from it form patches (area,
  mean ΔE of the blocks above half the peak).
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass
from math import erf, sqrt

import numpy as np
from numba import njit
from scipy import ndimage

from contract.findings import (
    ColorMeasurements,
    DentMeasurements,
    ScratchMeasurements,
    SurfaceMeasurements,
    revised,
)
from services.defects.morphology import dilate, erode, label8
from services.defects.panels import Panels
from services.defects.raster import Raster, block_cells, block_sums
from services.defects.smoothing import across, down, gaussian_kernel, gaussian_pair
from services.lib.pointcloud.color import delta_e, srgb_to_lab
from services.lib.tasks import Helping, start_helping

EIGHT_CONNECTED = np.ones((3, 3), bool)


@dataclass(frozen=True)
class SurfaceConfig:
    edge_margin_mm: float = 3.0
    """Panel border left out (rounded edges)."""
    smooth_mm: float = 25.0
    dent_detect_mm: float = 0.06
    dent_min_diameter_mm: float = 2.0
    scratch_sigma: float = 3.5
    scratch_background_mm: float = 1.5
    scratch_min_length_mm: float = 3.0
    scratch_min_depth_mm: float = 0.04
    relief_rim_mm: float = 4.0
    """No scratch is looked for this close to a dent or bump."""
    color_detect: float = 2.0
    color_min_area_mm2: float = 3.0


@dataclass(frozen=True)
class SurfaceFinding:
    type: str
    """dent, bump, scratch or color."""
    panel: int
    at_uv: np.ndarray
    value: float
    """Depth (mm) of dents, bumps and scratches; ΔE of colour patches."""
    extent_mm: float
    """Diameter (dents, bumps, colour: of the circle of the same area) or length."""
    measurements: SurfaceMeasurements
    confidence: float


def _blocks(values: np.ndarray, mask: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Means of (rows, cols) float32 ``values`` over the ``mask`` cells of each block of
    ``block`` × ``block`` cells (NaN where none), and the number of them, float32."""
    total, weight = _block_totals(values, mask, block)
    with np.errstate(invalid="ignore", divide="ignore"):
        return total / weight, weight


@njit(cache=True, nogil=True)
def _block_totals(
    values: np.ndarray, mask: np.ndarray, block: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per block: the sum of the float32 ``values`` on the ``mask`` cells and their count,
    in one pass, added in ``block_sums``' order (along each cell row of a block, then over
    its rows, the cells beyond the map counting 0): the same float32 sums as
    ``block_sums(np.where(mask, values, 0) * mask, block)``."""
    rows, cols = values.shape
    block_rows, block_cols = -(-rows // block), -(-cols // block)
    total = np.empty((block_rows, block_cols), np.float32)
    weight = np.empty((block_rows, block_cols), np.float32)
    zero = np.float32(0.0)
    for r in range(block_rows):
        for k in range(block):
            i = r * block + k
            for b in range(block_cols):
                row_total, row_weight = zero, zero
                for m in range(block):
                    j = b * block + m
                    inside = i < rows and j < cols and mask[i, j]
                    value = values[i, j] if inside else zero
                    one = np.float32(1.0) if inside else zero
                    if m == 0:
                        row_total, row_weight = value, one
                    else:
                        row_total += value
                        row_weight += one
                if k == 0:
                    total[r, b], weight[r, b] = row_total, row_weight
                else:
                    total[r, b] += row_total
                    weight[r, b] += row_weight
    return total, weight


def _normalised_smooth(values: np.ndarray, weights: np.ndarray, sigma: float) -> np.ndarray:
    """Σ G·w·v / Σ G·w with a Gaussian G of ``sigma`` cells. A wide one is taken on
    coarser cells (σ ≥ 3 of them, weighted means) and interpolated back: what it smooths
    away is far finer than those cells."""
    weighted = np.where(weights > 0, values * weights, 0.0)
    factor = int(sigma // 3)
    if factor > 1:
        weighted, weights = block_sums(weighted, factor), block_sums(weights, factor)
    numerator, denominator = gaussian_pair(
        weighted, weights.astype(weighted.dtype), sigma / max(factor, 1)
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = numerator / denominator
    return _upsample(smooth, factor, values.shape) if factor > 1 else smooth


def _upsample(blocks: np.ndarray, block: int, shape: tuple[int, int]) -> np.ndarray:
    """Bilinear interpolation of (rows, cols) block values at the centres of the ``shape``
    cells they cover (edge blocks held constant beyond their centres), in the blocks'
    dtype: along the rows, then along the columns."""
    nothing = np.zeros((0, 0), blocks.dtype)
    return _interpolate(blocks, *_steps(blocks, block, shape), nothing, nothing.astype(bool))


def _below(height: np.ndarray, inside: np.ndarray, blocks: np.ndarray, block: int) -> np.ndarray:
    """``np.where(inside, height − _upsample(blocks, block, height.shape), NaN)`` (all
    float32) in one pass: the fine cells' height above a surface given on the blocks."""
    return _interpolate(blocks, *_steps(blocks, block, height.shape), height, inside)


def _steps(blocks: np.ndarray, block: int, shape: tuple[int, int]) -> list[np.ndarray]:
    """Per axis: the lower and upper block of each output cell, and its weight t."""
    steps = []
    for axis in (0, 1):
        n = blocks.shape[axis]
        at = np.clip((np.arange(shape[axis]) + 0.5) / block - 0.5, 0, n - 1)
        low = np.minimum(at.astype(np.int64), max(n - 2, 0))
        steps += [low, np.minimum(low + 1, n - 1), (at - low).astype(blocks.dtype)]
    return steps


@njit(cache=True, nogil=True)
def _interpolate(
    blocks: np.ndarray,
    low_row: np.ndarray,
    high_row: np.ndarray,
    t_row: np.ndarray,
    low_col: np.ndarray,
    high_col: np.ndarray,
    t_col: np.ndarray,
    height: np.ndarray,
    inside: np.ndarray,
) -> np.ndarray:
    """a + (b − a)·t between the blocks ``low`` and ``high`` of each output row, then of
    each output column: the two NumPy passes of ``_upsample`` in one, each output row
    written once (the same operations, in the blocks' dtype, so the same values). Given a
    ``height`` map of the output's shape (not (0, 0)): ``height`` less that on the
    ``inside`` cells, NaN elsewhere."""
    out = np.empty((low_row.shape[0], low_col.shape[0]), blocks.dtype)
    row = np.empty(blocks.shape[1], blocks.dtype)  # the blocks interpolated along the rows
    below = height.shape[0] > 0
    for i in range(low_row.shape[0]):
        a, b, t = blocks[low_row[i]], blocks[high_row[i]], t_row[i]
        for j in range(blocks.shape[1]):
            row[j] = a[j] + (b[j] - a[j]) * t
        for j in range(low_col.shape[0]):
            left, right = row[low_col[j]], row[high_col[j]]
            value = left + (right - left) * t_col[j]
            if below:
                out[i, j] = height[i, j] - value if inside[i, j] else np.nan
            else:
                out[i, j] = value
    return out


def _reference(
    uv: np.ndarray, height: np.ndarray, inside: np.ndarray, smooth_blocks: float
) -> tuple[np.ndarray, np.ndarray]:
    """Robust reference surface on the blocks of one panel and its inlier mask."""
    points = uv[inside]
    scale = np.maximum(np.array([np.ptp(points[:, 0]), np.ptp(points[:, 1])]), 1.0) / 2
    centre = points.mean(0)
    a, b = ((uv - centre) / scale).transpose(2, 0, 1)
    powers_a, powers_b = [np.ones_like(a)], [np.ones_like(b)]
    for _ in range(3):
        powers_a.append(powers_a[-1] * a)
        powers_b.append(powers_b[-1] * b)
    design = np.stack([powers_a[i] * powers_b[j] for i in range(4) for j in range(4 - i)], -1)
    coef, weight = _tukey_fit(np.ascontiguousarray(design[inside].T), height[inside], 6)
    surface = design @ coef
    inlier = np.zeros(inside.shape, bool)
    inlier[inside] = weight > 0
    detail = _normalised_smooth(height - surface, inlier.astype(np.float64), smooth_blocks)
    return surface + np.where(np.isfinite(detail), detail, 0.0), inlier


@njit(cache=True, nogil=True)
def _tukey_fit(
    design_t: np.ndarray, target: np.ndarray, iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of design @ coef ≈ ``target`` reweighted ``iterations`` times with
    Tukey's biweight (c = 4.685 robust σ of the residual): (coef, final weights), the
    (terms, n) ``design_t`` given transposed. Compiled: these passes over a panel's blocks
    otherwise hold the GIL, and the panels are fitted on several threads. The normal
    equations are the dot products of the weighted terms, each pair once (contiguous rows:
    vectorised, and half the work of two matrix products)."""
    m, n = design_t.shape
    weight = np.ones(n)
    coef = np.zeros(m)
    weighted = np.empty(n)
    residual = np.empty(n)
    for _ in range(iterations):
        normal, rhs = np.empty((m, m)), np.empty(m)
        for p in range(m):
            term = design_t[p]
            for i in range(n):
                weighted[i] = term[i] * weight[i]
            rhs[p] = np.dot(weighted, target)
            for q in range(p, m):
                normal[p, q] = normal[q, p] = np.dot(weighted, design_t[q])
            normal[p, p] += 1e-9
        coef = np.linalg.solve(normal, rhs)
        residual[:] = target
        for p in range(m):
            c, term = coef[p], design_t[p]
            for i in range(n):
                residual[i] -= c * term[i]
        sigma = max(1.4826 * np.median(np.abs(residual)), 1e-4)
        for i in range(n):
            x = residual[i] / (4.685 * sigma)
            weight[i] = max(1.0 - x * x, 0.0) ** 2
    return coef, weight


def _mean3(deviation: np.ndarray, inside: np.ndarray, window: tuple[slice, slice]) -> np.ndarray:
    """The 3 × 3 mean of ``deviation`` over the ``inside`` cells, in ``window`` only (0
    outside): computed on the window grown by a cell, so it equals the whole map's."""
    grown = tuple(
        slice(max(w.start - 1, 0), min(w.stop + 1, n))
        for w, n in zip(window, deviation.shape, strict=True)
    )
    crop = tuple(
        slice(w.start - g.start, w.start - g.start + min(w.stop, n) - w.start)
        for w, g, n in zip(window, grown, deviation.shape, strict=True)
    )
    mask = inside[grown]
    total = ndimage.uniform_filter(np.where(mask, deviation[grown], 0.0), 3)
    weight = np.maximum(ndimage.uniform_filter(mask.astype(np.float32), 3), 1e-9)
    return np.where(mask, total / weight, 0.0)[crop]


def _shape(rows: np.ndarray, cols: np.ndarray, cell_mm: float) -> tuple[float, float, np.ndarray]:
    """(length, width, direction) of a region from the spread along its principal axes
    (a uniform bar of length L has standard deviation L / √12)."""
    if len(rows) < 3:
        return cell_mm, cell_mm, np.array([1.0, 0.0])
    # The 2 × 2 covariance's eigen-decomposition in closed form (np.cov and eigh cost
    # more in call overhead than the regions in work).
    r, c = rows - rows.mean(), cols - cols.mean()
    n = len(rows) - 1
    a, b, d = float(r @ r) / n, float(r @ c) / n, float(c @ c) / n
    half_sum, root = (a + d) / 2, float(np.hypot((a - d) / 2, b))
    values = np.array([half_sum - root, half_sum + root]) * cell_mm**2
    spread = np.sqrt(np.maximum(values, 0.0) * 12) + cell_mm
    if b != 0.0:
        direction = np.array([b, half_sum + root - a])
    else:
        direction = np.array([1.0, 0.0]) if a >= d else np.array([0.0, 1.0])
    return float(spread[1]), float(spread[0]), direction / np.linalg.norm(direction)


def block_lab(raster: Raster) -> np.ndarray | None:
    """(block rows, block cols, 3) L*a*b* of the raster's mean block colours (NaN where
    none), None without colours: what ``find_surface_defects`` cuts each panel's from."""
    return None if raster.block_rgb is None else _block_lab(raster.block_rgb)


def find_surface_defects(
    raster: Raster,
    panels: Panels,
    config: SurfaceConfig,
    lab: np.ndarray | None,
    pool: Executor | None = None,
    helpers: int = 1,
) -> Helping:
    """Dents, bumps, scratches and (given the ``block_lab`` of the raster) colour patches,
    panel by panel, started on up to ``helpers`` of ``pool``'s threads at once, the
    largest panel first (so that the last to finish is a small one); ``finish()`` joins
    them and returns each panel's findings, in label order."""
    labels = [label for label, box in enumerate(panels.boxes, start=1) if box is not None]
    boxes = [panels.boxes[label - 1] for label in labels]
    cells = [(rows.stop - rows.start) * (cols.stop - cols.start) for rows, cols in boxes]

    def run(label: int, box: tuple[slice, slice]) -> list[SurfaceFinding]:
        return _panel(raster, lab, panels.labels, label, box, config)

    return start_helping(pool, run, labels, boxes, sizes=cells, helpers=helpers)


def _panel(
    raster: Raster,
    lab: np.ndarray | None,
    labels: np.ndarray,
    label: int,
    found: tuple[slice, slice],
    config: SurfaceConfig,
) -> list[SurfaceFinding]:
    cell = raster.cell_mm
    block = block_cells(cell)
    margin = max(1, int(round(config.edge_margin_mm / cell)))
    # Work in the panel's bounding box, aligned to whole blocks.
    r0, r1 = found[0].start - found[0].start % block, found[0].stop
    c0, c1 = found[1].start - found[1].start % block, found[1].stop
    box = (slice(r0, r1), slice(c0, c1))
    # More than ``margin`` cells from anything not this panel (the box's outside too).
    inside = erode(labels[box] == label, margin)
    height = raster.height[box]  # float32 on the fine cells: half the memory traffic
    inside &= np.isfinite(height)
    if inside.sum() < 100:
        return []
    coarse, weight = _blocks(height, inside, block)
    coarse_inside = weight >= 0.5 * block * block  # blocks at least half inside
    findings = _relief(
        raster, label, height, inside, coarse, weight, coarse_inside, (r0, c0), block, config
    )
    if lab is not None:
        lab_box = (slice(r0 // block, -(-r1 // block)), slice(c0 // block, -(-c1 // block)))
        findings += _color(
            raster,
            label,
            lab[lab_box],
            coarse_inside,
            (r0, c0),
            block,
            config,
        )
    return findings


def _relief(
    raster: Raster,
    label: int,
    height: np.ndarray,
    inside: np.ndarray,
    coarse: np.ndarray,
    weight: np.ndarray,
    coarse_inside: np.ndarray,
    origin: tuple[int, int],
    block: int,
    config: SurfaceConfig,
) -> list[SurfaceFinding]:
    """Dents, bumps and scratches on the ``inside`` cells of a panel's box, with their
    ``_blocks`` mean ``coarse`` height and ``weight``, ``coarse_inside`` the blocks at
    least half inside."""
    cell = raster.cell_mm
    coarse, weight = coarse.astype(np.float64), weight.astype(np.float64)
    b_rows, b_cols = np.meshgrid(
        np.arange(coarse.shape[0]), np.arange(coarse.shape[1]), indexing="ij"
    )
    uv = raster.centres_uv(
        origin[0] + (b_rows + 0.5) * block - 0.5, origin[1] + (b_cols + 0.5) * block - 0.5
    )
    block_mm = block * cell
    reference, _ = _reference(uv, coarse, coarse_inside, config.smooth_mm / block_mm)
    deviation = _below(height, inside, reference.astype(np.float32), block)
    # The scratches' background: the deviation smoothed on the blocks (a block is well
    # under the smoothing's σ, so this is the fine smoothing at 1/25 of the work).
    background = _upsample(
        _normalised_smooth(
            np.where(coarse_inside, coarse - reference, 0.0),
            np.where(coarse_inside, weight, 0.0),
            config.scratch_background_mm / block_mm,
        ).astype(np.float32),
        block,
        height.shape,
    )
    findings = []
    coarse_deviation = np.where(coarse_inside, coarse - reference, 0.0)
    relief_mask = np.zeros(height.shape, bool)
    regions, count = ndimage.label(
        np.abs(coarse_deviation) > config.dent_detect_mm, EIGHT_CONNECTED
    )
    for index, found in enumerate(ndimage.find_objects(regions), start=1):
        own = regions[found] == index
        fine = (
            slice(found[0].start * block, found[0].stop * block),
            slice(found[1].start * block, found[1].stop * block),
        )
        smoothed = _mean3(deviation, inside, fine)
        own_fine = np.repeat(np.repeat(own, block, 0), block, 1)[
            : smoothed.shape[0], : smoothed.shape[1]
        ]
        values = np.where(own_fine, smoothed, 0.0)
        peak = np.unravel_index(np.argmax(np.abs(values)), values.shape)
        depth = float(values[peak])
        core = own_fine & (np.abs(values) >= abs(depth) / 4) & (np.sign(values) == np.sign(depth))
        diameter = 2 * np.sqrt(core.sum() * cell * cell / np.pi)
        length, width, _ = _shape(*np.nonzero(core), cell)
        if diameter < config.dent_min_diameter_mm or length > 4 * width:
            continue  # thin: a scratch's business
        if diameter >= 2 * config.relief_rim_mm:  # a small pit's foot is no groove
            relief_mask[fine] |= own_fine
        at = raster.centres_uv(
            origin[0] + fine[0].start + peak[0], origin[1] + fine[1].start + peak[1]
        )
        findings.append(
            SurfaceFinding(
                "dent" if depth < 0 else "bump",
                label,
                at,
                abs(depth),
                float(diameter),
                DentMeasurements(depth_mm=abs(depth), diameter_mm=float(diameter)),
                _confidence(abs(depth), config.dent_detect_mm, 0.01),
            )
        )
    # The foot of a dent or bump curves like a groove: keep scratches off its rim.
    rim = int(np.ceil(config.relief_rim_mm / cell))
    near_relief = dilate(relief_mask, rim) if relief_mask.any() else relief_mask
    scratches = _join_collinear(
        _scratches(raster, label, deviation, background, inside, near_relief, origin, config)
    )
    return [f for f in findings if not any(_on_scratch(f, s) for s in scratches)] + scratches


def _join_collinear(
    scratches: list[SurfaceFinding], gap_mm: float = 10.0, offset_mm: float = 1.0
) -> list[SurfaceFinding]:
    """Pieces of one scratch (a narrow groove breaks up where the sampling misses it) into
    one: pieces in line (≤ 10°, ≤ ``offset_mm`` apart across) with ≤ ``gap_mm`` between."""
    pieces = list(scratches)
    joined = True
    while joined:
        joined = False
        for i in range(len(pieces)):
            for j in range(i + 1, len(pieces)):
                a, b = pieces[i], pieces[j]
                da = np.array(a.measurements.direction_uv)
                db = np.array(b.measurements.direction_uv)
                offset = b.at_uv - a.at_uv
                across = abs(offset @ np.array([-da[1], da[0]]))
                between = abs(offset @ da) - (a.extent_mm + b.extent_mm) / 2
                if (
                    abs(da @ db) > np.cos(np.radians(10))
                    and across <= offset_mm
                    and between <= gap_mm
                ):
                    pieces[i] = _merged(a, b, da)
                    del pieces[j]
                    joined = True
                    break
            if joined:
                break
    return pieces


def _merged(a: SurfaceFinding, b: SurfaceFinding, direction: np.ndarray) -> SurfaceFinding:
    ends = [f.at_uv + sign * f.extent_mm / 2 * direction for f in (a, b) for sign in (-1, 1)]
    along = [e @ direction for e in ends]
    first, last = ends[int(np.argmin(along))], ends[int(np.argmax(along))]
    length = float(np.linalg.norm(last - first))
    depth = max(a.value, b.value)
    width = (a.measurements.width_mm * a.extent_mm + b.measurements.width_mm * b.extent_mm) / (
        a.extent_mm + b.extent_mm
    )
    measurements = revised(a.measurements, depth_mm=depth, length_mm=length, width_mm=width)
    return SurfaceFinding(
        "scratch",
        a.panel,
        (first + last) / 2,
        depth,
        length,
        measurements,
        max(a.confidence, b.confidence),
    )


def _on_scratch(finding: SurfaceFinding, scratch: SurfaceFinding, margin_mm: float = 2.0) -> bool:
    """Whether a small dent lies on a scratch (its deepest part, seen as a round pit)."""
    direction = np.array(scratch.measurements.direction_uv)
    offset = finding.at_uv - scratch.at_uv
    along = abs(offset @ direction)
    across = abs(offset @ np.array([-direction[1], direction[0]]))
    small = finding.extent_mm < 2 * margin_mm + scratch.measurements.width_mm
    return small and along <= scratch.extent_mm / 2 + margin_mm and across <= margin_mm


def _scratches(
    raster: Raster,
    label: int,
    deviation: np.ndarray,
    background: np.ndarray,
    inside: np.ndarray,
    relief: np.ndarray,
    origin: tuple[int, int],
    config: SurfaceConfig,
) -> list[SurfaceFinding]:
    """Scratches in ``deviation``, the height above the panel's reference surface (tilt
    and curvature removed, so smoothing near the panel's border stays unbiased), against
    its smooth ``background``."""
    cell = raster.cell_mm
    depth, sample = _depth_below_band(deviation, inside, background, relief, gaussian_kernel(1.0))
    # The noise level from every 4th cell: as good an estimate at a quarter of the work.
    noise = 1.4826 * float(np.median(np.abs(sample))) if len(sample) else 0.0
    noise = max(noise, 1e-5)
    score, seeded = _scores(depth, np.float32(noise), config.scratch_sigma)
    grown, boxes = label8(seeded)
    findings = []
    for index in np.unique(grown[score > config.scratch_sigma + 2]).tolist():  # with a seed
        row0, col0, row1, col1 = boxes[index - 1]
        found = (slice(row0, row1 + 1), slice(col0, col1 + 1))
        own = grown[found] == index
        rows, cols = np.nonzero(own)
        length, width, direction = _shape(rows, cols, cell)
        if length < config.scratch_min_length_mm or length < 4 * width:
            continue  # not thin (most regions: the noise's)
        raw_depth = (background[found] - deviation[found])[own]  # own ⊂ clear
        deepest = float(np.percentile(raw_depth, 98))
        if deepest < config.scratch_min_depth_mm:
            continue
        # A parabolic groove's section is ⅔ width × depth.
        section_mm2 = float(np.clip(raw_depth, 0, None).sum()) * cell * cell / length
        width = float(np.clip(1.5 * section_mm2 / max(deepest, 1e-6), cell / 2, width))
        centre = np.array([rows.mean(), cols.mean()])
        at = raster.centres_uv(
            origin[0] + found[0].start + centre[0], origin[1] + found[1].start + centre[1]
        )
        findings.append(
            SurfaceFinding(
                "scratch",
                label,
                at,
                deepest,
                length,
                ScratchMeasurements(
                    depth_mm=deepest,
                    length_mm=length,
                    width_mm=width,
                    direction_uv=tuple(direction.tolist()),
                ),
                _confidence(float(score[found][own].max()), config.scratch_sigma, 1.0),
            )
        )
    return findings


@njit(cache=True, nogil=True, error_model="numpy")  # 0 / 0 is NaN, as in NumPy
def _depth_below_band(
    deviation: np.ndarray,
    inside: np.ndarray,
    background: np.ndarray,
    relief: np.ndarray,
    kernel: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """How far the normalised smoothing of the ``inside`` cells' float32 ``deviation`` by
    the Gaussian ``kernel`` lies below the ``background``, on the ``inside`` cells clear of
    ``relief`` (0 elsewhere); and those clear cells' values on every other row and column
    (the noise's sample).

    With weights of 0 or 1 the weighted heights are the heights: this is
    ``gaussian_pair(np.where(inside, deviation, 0), inside.astype(np.float32), σ)`` and
    ``np.where(clear, -(numerator / denominator − background), 0)``, float32 as those give
    it, in one pass: each smoothed row is used as it is made, not stored and read back."""
    rows, cols = deviation.shape
    taps = kernel.shape[0]
    radius = taps // 2
    height, weight = np.empty((1, cols), np.float32), np.empty((1, cols), np.float32)
    ring_height, ring_weight = np.empty((2, taps, cols), np.float32)
    line_height, line_weight = np.empty(cols + 2 * radius), np.empty(cols + 2 * radius)
    sum_height, sum_weight = np.empty(cols), np.empty(cols)
    depth = np.zeros((rows, cols), np.float32)
    sample = np.empty(-(-rows // 2) * -(-cols // 2), np.float32)
    n = 0
    ready = 0  # rows smoothed across
    for i in range(rows):
        while ready < min(rows, i + radius + 1):
            for j in range(cols):
                height[0, j] = deviation[ready, j] if inside[ready, j] else np.float32(0.0)
                weight[0, j] = np.float32(1.0) if inside[ready, j] else np.float32(0.0)
            across(height, weight, kernel, 0, line_height, line_weight, sum_height, sum_weight)
            ring_height[ready % taps] = sum_height
            ring_weight[ready % taps] = sum_weight
            ready += 1
        down(ring_height, ring_weight, kernel, i, rows, sum_height, sum_weight)
        for j in range(cols):
            if inside[i, j] and not relief[i, j]:
                smooth = np.float32(sum_height[j]) / np.float32(sum_weight[j])
                band = np.float32(smooth) - background[i, j]
                depth[i, j] = -band
                if i % 2 == 0 and j % 2 == 0:
                    sample[n] = -band
                    n += 1
    return depth, sample[:n]


@njit(cache=True, nogil=True)
def _scores(depth: np.ndarray, noise: np.float32, level: float) -> tuple[np.ndarray, np.ndarray]:
    """``depth`` / ``noise`` (float32), and where it exceeds ``level``."""
    score = np.empty(depth.shape, np.float32)
    above = np.empty(depth.shape, np.bool_)
    for i in range(depth.shape[0]):
        for j in range(depth.shape[1]):
            score[i, j] = depth[i, j] / noise
            above[i, j] = score[i, j] > level
    return score, above


def _block_lab(mean: np.ndarray) -> np.ndarray:
    """(rows, cols, 3) L*a*b* of blocks' (rows, cols, 3) mean sRGB (NaN where none)."""
    lab = srgb_to_lab(np.clip(np.nan_to_num(mean), 0, 255))
    lab[~np.isfinite(mean).all(-1)] = np.nan
    return lab


def _color(
    raster: Raster,
    label: int,
    lab: np.ndarray,
    inside: np.ndarray,
    origin: tuple[int, int],
    block: int,
    config: SurfaceConfig,
) -> list[SurfaceFinding]:
    inside = inside & np.isfinite(lab).all(-1)
    if inside.sum() < 10:
        return []
    base = np.median(lab[inside], axis=0)
    inlier = inside & (delta_e(lab, base) < config.color_detect)
    reference = np.stack(
        [
            _normalised_smooth(
                lab[..., c], inlier.astype(np.float64), config.smooth_mm / (block * raster.cell_mm)
            )
            for c in range(3)
        ],
        -1,
    )
    reference = np.where(np.isfinite(reference), reference, base)
    difference = np.where(inside, delta_e(lab, reference), 0.0)
    regions, _ = ndimage.label(difference > config.color_detect, EIGHT_CONNECTED)
    findings = []
    block_mm = block * raster.cell_mm
    for index, found in enumerate(ndimage.find_objects(regions), start=1):
        own = regions[found] == index
        area = float(own.sum()) * block_mm**2
        if area < config.color_min_area_mm2:
            continue
        values = np.where(own, difference[found], 0.0)
        core = values >= values.max() / 2
        mean_delta = float(values[core].mean())
        rows, cols = np.nonzero(own)
        at = raster.centres_uv(
            origin[0] + (found[0].start + rows.mean() + 0.5) * block - 0.5,
            origin[1] + (found[1].start + cols.mean() + 0.5) * block - 0.5,
        )
        diameter = 2 * np.sqrt(area / np.pi)
        findings.append(
            SurfaceFinding(
                "color",
                label,
                at,
                mean_delta,
                float(diameter),
                ColorMeasurements(
                    delta_e=mean_delta, peak_delta_e=float(values.max()), area_mm2=area
                ),
                _confidence(mean_delta, config.color_detect, 0.5),
            )
        )
    return findings


def _confidence(value: float, threshold: float, sigma: float) -> float:
    """How sure a finding is real: the normal probability that a value measured this far
    above the detection threshold, with this uncertainty, is not noise."""
    return float(0.5 * (1 + erf((value - threshold) / (sigma * sqrt(2)))))
