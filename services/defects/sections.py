"""Cross-sections along a seam: gap and step from the points, section by section.

A section is the slab of points within ``slab_mm / 2`` of a plane across the seam. In it,
with x the across coordinate and w the height (the surface frame's normal):

1. The gap shows as the widest empty stretch of x near the seam's centre line (points of
   the backing structure, far below, are left out first); its two ends are where each
   panel's last measured point lies.
2. Each panel's top is a plane w = α + β·x + γ·y (y along the seam) fitted to its points
   between ``edge_band_mm`` and ``edge_band_mm + top_band_mm`` from that end.
3. In the frame of that top (x' along it, δ the depth below it) the rounded edge is a
   quarter circle of radius ρ tangent to the top at x' = x_c, ending in the vertical side
   face x' = x_c + ρ. The sensor sees the arc up to its incidence limit (and, from
   oblique views, part of the side face); x_c and ρ are fitted to those points (least
   squares on the distance to the arc or the face). ρ is a property of the edge, so a
   second pass fixes it at its median over the seam and fits x_c alone.
4. Gap = distance between the two side faces along the mean top direction; step = the
   offset of panel b's top over panel a's, along the mean top normal, at the seam centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from services.defects.seams import SeamLine

MIN_POINTS = 8


@dataclass(frozen=True)
class SectionConfig:
    pitch_mm: float = 2.0
    slab_mm: float = 1.0
    edge_band_mm: float = 2.5
    """Points closer than this to a panel's end belong to its rounded edge; more than the
    largest edge radius expected."""
    top_band_mm: float = 6.0
    end_margin_mm: float = 3.0
    """Sections stop this far (plus the half band of the seams around) from a seam's ends,
    clear of crossing seams and the rounded corners."""
    decision_sections: int = 5
    """Gap and step are judged against the tolerances on their running median over this
    many sections (10 mm at the default pitch)."""
    edge_model: str = "arc"
    """``arc``: the side faces from the fitted rounded edges (vista). ``void``: the last
    measured point of each panel, what a single-profile gap gauge reports (the peer in
    ``vista bench defects``)."""


@dataclass(frozen=True)
class SeamProfile:
    seam: SeamLine
    along_mm: np.ndarray
    """(K,) section positions along the seam line."""
    gap_mm: np.ndarray
    step_mm: np.ndarray
    at_local: np.ndarray
    """(K, 3) (u, v, w) of each section's centre on the mean top."""
    normal_local: np.ndarray
    """(K, 3) mean top normal of each section in the surface frame."""
    edge_radius_mm: tuple[float, float]
    """Fitted radius of the rounded edge of panel a and b."""
    fit_rms_mm: np.ndarray
    """(K,) RMS distance of the edge points to the fitted edges."""


def reach_mm(seam: SeamLine, config: SectionConfig) -> float:
    """How far across its centre line a seam's sections take points: the band, the edge
    band and the top band on each side, and 1 mm to spare."""
    return seam.half_band_mm + config.edge_band_mm + config.top_band_mm + 1.0


def section_range(
    seam: SeamLine, config: SectionConfig, *, end_margin_mm: float
) -> tuple[float, int]:
    """Position along the seam line of the first section, and how many there are."""
    first = seam.start_mm + end_margin_mm
    return first, int(np.floor((seam.end_mm - end_margin_mm - first) / config.pitch_mm)) + 1


def profile_seam(
    slab: np.ndarray, seam: SeamLine, config: SectionConfig, first: float, count: int
) -> SeamProfile | None:
    """Measure the ``count`` sections of ``seam`` from ``first`` on, given the points in
    their slabs as (4, M) rows (section k, y along from its plane, x across, height w;
    ``binning.seam_slabs``)."""
    k, y, x, w = slab[0].astype(np.int64), slab[1], slab[2], slab[3]
    ends = _gap_ends(k, x, w, seam, config, count)
    if ends is None:
        return None
    end_a, end_b, valid, floor = ends
    keep = w >= floor[k]
    k, y, x, w = k[keep], y[keep], x[keep], w[keep]
    # Both sides as "side a": side b mirrored so its edge also faces +x.
    side = (x > (end_a[k] + end_b[k]) / 2).astype(np.int64)
    xm = np.where(side == 0, x - end_a[k], end_b[k] - x)
    group = 2 * k + side
    tops = _fit_tops(group, xm, w, y, config, 2 * count)
    if config.edge_model == "void":
        edge_x, radius, rms = np.zeros(2 * count), np.full(2, np.nan), np.zeros(2 * count)
    else:
        edge_x, radius, rms = _fit_edges(group, xm, w, y, tops, config, 2 * count)
    alpha, beta = tops[:, 0], tops[:, 1]
    # Back to the section's (x, w): the side faces at top level, and the top directions.
    norm = np.sqrt(1 + beta**2)
    face_x = edge_x / norm
    face_w = alpha + beta * face_x
    ea = np.stack([end_a + face_x[0::2], face_w[0::2]], 1)
    eb = np.stack([end_b - face_x[1::2], face_w[1::2]], 1)
    tau = np.stack(
        [1 / norm[0::2] + 1 / norm[1::2], beta[0::2] / norm[0::2] - beta[1::2] / norm[1::2]], 1
    )
    tau /= np.linalg.norm(tau, axis=1, keepdims=True)
    gap = np.sum((eb - ea) * tau, axis=1)
    mid = (ea[:, 0] + eb[:, 0]) / 2
    wa = alpha[0::2] + beta[0::2] * (mid - end_a)
    wb = alpha[1::2] + beta[1::2] * (end_b - mid)
    step = (wb - wa) * tau[:, 0]
    valid &= np.isfinite(gap) & np.isfinite(step) & np.isfinite(edge_x[0::2] + edge_x[1::2])
    positions = first + np.arange(count) * config.pitch_mm
    at_uv = seam.point_uv(positions) + np.multiply.outer(mid, seam.across_uv)
    at = np.column_stack([at_uv, (wa + wb) / 2])
    normal_2d = np.stack([-tau[:, 1], tau[:, 0]], 1)
    normal = np.column_stack([np.multiply.outer(normal_2d[:, 0], seam.across_uv), normal_2d[:, 1]])
    return SeamProfile(
        seam,
        positions[valid],
        gap[valid],
        step[valid],
        at[valid],
        normal[valid],
        (float(radius[0]), float(radius[1])),
        np.maximum(rms[0::2], rms[1::2])[valid],
    )


def _gap_ends(
    k: np.ndarray,
    x: np.ndarray,
    w: np.ndarray,
    seam: SeamLine,
    config: SectionConfig,
    count: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Per section: the last point of panel a and the first of panel b around the widest
    empty stretch near the centre line, whether one was found, and the height below which
    points belong to the backing, not the panels."""
    outer = np.abs(x) > seam.half_band_mm + config.edge_band_mm
    tops = np.full((count, 2), np.nan)
    for side in (0, 1):
        on = outer & ((x > 0) == bool(side))
        total = np.bincount(k[on], weights=w[on], minlength=count)
        tops[:, side] = total / np.maximum(np.bincount(k[on], minlength=count), 1)
    floor = np.nanmin(tops, axis=1) - (config.edge_band_mm + 1.5)
    floor = np.where(np.isfinite(floor), floor, np.inf)
    near = (np.abs(x) < seam.half_band_mm + 1.5) & (w >= floor[k])
    if near.sum() < 2:
        return None
    end_a, end_b, width = _widest_gaps(k, x, near, count)
    valid = (width > 0) & np.isfinite(tops).all(axis=1)
    end_a = np.where(valid, end_a, 0.0)
    end_b = np.where(valid, end_b, 0.0)
    return end_a, end_b, valid, floor


def _fit_tops(
    group: np.ndarray,
    xm: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    config: SectionConfig,
    groups: int,
) -> np.ndarray:
    """(groups, 3) α, β, γ of each side's top plane w = α + β·xm + γ·y."""
    sums = _top_sums(
        group, xm, w, y, -config.edge_band_mm - config.top_band_mm, -config.edge_band_mm, groups
    )
    basis_products = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    normal = np.zeros((groups, 3, 3))
    for row, (i, j) in enumerate(basis_products):
        normal[:, i, j] = normal[:, j, i] = sums[row]
    rhs = sums[6:9].T
    enough = sums[0] >= MIN_POINTS
    normal[~enough] = np.eye(3)
    solution = np.linalg.solve(normal, rhs[..., None])[..., 0]
    solution[~enough] = np.nan
    return solution


def _fit_edges(
    group: np.ndarray,
    xm: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    tops: np.ndarray,
    config: SectionConfig,
    groups: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per group: the side face's position along the top (x' of the face), the edge radius
    used, and the RMS residual; see the module docstring, step 3."""
    near = xm > -config.edge_band_mm
    g, xm, w, y = group[near], xm[near], w[near], y[near]
    alpha, beta, gamma = (tops[g, i] for i in range(3))
    norm = np.sqrt(1 + beta**2)
    flat_w = w - gamma * y
    xp = (xm + beta * (flat_w - alpha)) / norm
    depth = (alpha + beta * xm - flat_w) / norm
    last = np.full(groups, -np.inf)
    np.maximum.at(last, g, np.where(np.isfinite(xp), xp, -np.inf))
    radius = np.full(groups, 1.0)
    centre = last - 0.97 * radius
    centre, radius, _ = _fit_arc(g, xp, depth, centre, radius, groups, fit_radius=True)
    # The radius belongs to the whole edge: its median over the seam, side by side.
    fitted = [radius[s::2][np.isfinite(centre[s::2])] for s in (0, 1)]
    side_radius = np.array([np.median(r) if len(r) else np.nan for r in fitted])
    radius = np.tile(side_radius, groups // 2)
    centre = last - 0.97 * radius
    centre, radius, rms = _fit_arc(g, xp, depth, centre, radius, groups, fit_radius=False)
    return centre + radius, side_radius, rms


def _fit_arc(
    g: np.ndarray,
    xp: np.ndarray,
    depth: np.ndarray,
    centre: np.ndarray,
    radius: np.ndarray,
    groups: int,
    *,
    fit_radius: bool,
    tolerance_mm: float = 1e-5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Damped Gauss–Newton steps of the edge model (arc, then vertical face): 12 with the
    radius free, 6 with it fixed, or until no edge moves by more than ``tolerance_mm``
    (lost ones aside). Groups with too few points are lost (NaN)."""
    for _ in range(12 if fit_radius else 6):
        n, sq, a, b_c, b, d, b_r = _edge_sums(g, xp, depth, centre, radius, groups)
        rms = np.sqrt(sq / np.maximum(n, 1))
        a += 1e-6
        if fit_radius:
            d += 1e-6
            damp = 1e-3 * (a + d)
            det = (a + damp) * (d + damp) - b * b
            step_c = -((d + damp) * b_c - b * b_r) / det
            step_r = -((a + damp) * b_r - b * b_c) / det
        else:
            step_c, step_r = -b_c / a, np.zeros(groups)
        enough = n >= MIN_POINTS
        before = centre
        centre = np.where(enough, centre + np.clip(step_c, -0.5, 0.5), np.nan)
        radius = np.where(enough, np.clip(radius + np.clip(step_r, -0.5, 0.5), 0.05, 10.0), np.nan)
        rms = np.where(enough, rms, np.nan)
        moved = np.abs(centre - before)
        if not np.any(moved[np.isfinite(moved)] > tolerance_mm):
            break
    return centre, radius, rms


@njit(cache=True, nogil=True)
def _edge_sums(
    g: np.ndarray,
    xp: np.ndarray,
    depth: np.ndarray,
    centre: np.ndarray,
    radius: np.ndarray,
    groups: int,
) -> np.ndarray:
    """Per group, the normal equations of one Gauss–Newton step: (7, groups) rows n, Σr²,
    Σj_c², Σj_c·r, Σj_c·j_r, Σj_r², Σj_r·r over the points on the arc (x' ≥ x_c, δ < ρ;
    residual = distance to the centre − ρ) or on the face (δ ≥ ρ; residual x' − x_c − ρ)."""
    sums = np.zeros((7, groups))
    for i in range(g.shape[0]):
        k = g[i]
        c, r = centre[k], radius[k]
        dx, dz = xp[i] - c, depth[i] - r
        if depth[i] >= r:
            residual, j_c, j_r = dx - r, -1.0, -1.0
        elif xp[i] >= c:
            distance = max(np.hypot(dx, dz), 1e-9)
            residual, j_c, j_r = distance - r, -dx / distance, -dz / distance - 1.0
        else:
            continue
        if not np.isfinite(residual):
            continue
        sums[0, k] += 1.0
        sums[1, k] += residual * residual
        sums[2, k] += j_c * j_c
        sums[3, k] += j_c * residual
        sums[4, k] += j_c * j_r
        sums[5, k] += j_r * j_r
        sums[6, k] += j_r * residual
    return sums


@njit(cache=True, nogil=True)
def _top_sums(
    group: np.ndarray,
    xm: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    low: float,
    high: float,
    groups: int,
) -> np.ndarray:
    """Per group, the normal equations of the plane w = α + β·xm + γ·y through the points
    with ``low`` ≤ xm ≤ ``high``: (9, groups) rows Σ1, Σxm, Σy, Σxm², Σxm·y, Σy², Σw,
    Σxm·w, Σy·w."""
    sums = np.zeros((9, groups))
    for i in range(group.shape[0]):
        x = xm[i]
        if not low <= x <= high:
            continue
        k, b, h = group[i], y[i], w[i]
        sums[0, k] += 1.0
        sums[1, k] += x
        sums[2, k] += b
        sums[3, k] += x * x
        sums[4, k] += x * b
        sums[5, k] += b * b
        sums[6, k] += h
        sums[7, k] += x * h
        sums[8, k] += b * h
    return sums


@njit(cache=True, nogil=True)
def _widest_gaps(
    k: np.ndarray, x: np.ndarray, near: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per section k, the widest stretch between consecutive ``near`` points along x:
    its two ends and its width (−1 with fewer than two points)."""
    starts = np.zeros(count + 1, np.int64)
    for i in range(k.shape[0]):
        if near[i]:
            starts[k[i] + 1] += 1
    starts = np.cumsum(starts)
    xs = np.empty(starts[-1])
    fill = starts[:-1].copy()
    for i in range(k.shape[0]):
        if near[i]:
            xs[fill[k[i]]] = x[i]
            fill[k[i]] += 1
    end_a, end_b = np.zeros(count), np.zeros(count)
    width = np.full(count, -1.0)
    for s in range(count):
        section = np.sort(xs[starts[s] : starts[s + 1]])
        for j in range(section.shape[0] - 1):
            if section[j + 1] - section[j] > width[s]:
                width[s] = section[j + 1] - section[j]
                end_a[s], end_b[s] = section[j], section[j + 1]
    return end_a, end_b, width
