"""Cross-sections along a seam: gap and step from the points, section by section.

A section is the slab of points within ``slab_mm / 2`` of a plane across the seam. In it,
with x the across coordinate and w the height (the surface frame's normal):

1. Each panel's top is fitted as a plane w = α + β·x + γ·y (y along the seam), robustly,
   well away from the seam; the cloud's noise σ is estimated from its residuals.
2. The gap is split at the middle of the widest empty stretch near the seam's centre line
   (points of the backing structure, far below, left out). Each panel's *top end* is its
   last point within 3σ of its top, reached from the far band without a jump (so a spike
   at top height in the gap is not taken for the panel).
3. The top is refitted 2.5 to 8.5 mm inside the top end (ISO 5436-1's rule: fit the
   surfaces, not the edge zones; Gocator's "surface offset").
4. The edge zone — from 1.5 mm inside the top end to the gap's middle — is explained by
   one of the edge models of ``edges.py`` (square, chamfer, round, or the free fallback):
   each side of the seam gets the model with the least information criterion over a
   dozen of its sections, with the shape (radius or angle) shared along the seam (its
   median there); every section is then fitted with it. X, where each side face stands,
   and its uncertainty come out.
5. Gap and step (see ``SectionConfig.gap_mode``); each section's gap uncertainty from its
   two edges.
6. Self-checks: a section whose gap cannot be trusted is *unmeasured* and says why (no
   gap seen, too few top points, a poor edge fit with no model for the profile, a hole at
   the edge, a negative gap with no overlap, a gap narrower than two point spacings
   between square corners, an edge that may lie in the other panel's shadow).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit

from services.defects import edges
from services.defects.kinds import MeasureSettings
from services.defects.seams import SeamLine

MIN_POINTS = 8
SETTINGS = MeasureSettings.model_fields
TOP_JUMP_MM = 0.3
TOP_JUMP_SPACINGS = 2.5
"""A panel's top points are followed towards the gap until a jump this wide, or this many
point spacings where that is more (``top_jump_mm``)."""
START_WINDOW_MM = 2.0
"""A top is first fitted to its points within this of its median height…"""
MEDIAN_STRIDE = 8
"""…taken over every 8th point."""
SELECTION_SECTIONS = 12
"""Sections per seam (evenly spread) on which each side's edge model is chosen."""
NO_GAP, SIDE, CROSSING, NARROW, SHADOW = range(1, 6)
SHAPE_PHASE = 0.07
"""An arc's or a chamfer's shape pins its edge finer than its points are spaced, but not
finer than this share of the widest stretch its pooled profiles leave: sampled at one
phase (rows along or at 45° to the seam), the same few places on the shape in every
section bias it alike — rounded edges at 0.1 mm, rows along the seam, were off by up to
0.011 mm a seam with σ 0.007 (0.85 of their sections within 2σ; 0.97 with this). Where
the profiles' phase drifts, the stretch, and this, are a fraction of the spacing."""
ARC_FORM = 0.003
"""An arc places its side face no finer than this share of its radius: the radius its
seam's sections share carries their common error (the radii of 12 sections agree to
their noise, and their median's σ says nothing of what they all miss) — rounded edges of
3.5–4 mm at 0.05 mm spacing, grid 15°, were 0.009–0.012 mm off with σ 0.003–0.004."""
WIDE_ARC_STRETCHES = 2.0
"""An arc this many stretches of its profiles wide or more, seen at few places across, is
placed by its radius where no chamfer explains its points (``_ambiguity``); a narrower
one fits a chamfer's columns as the side face and its corner (chamfers of 0.3–1 mm at
0.5 mm fitted as arcs of 0.2–0.5 mm, 0.43 mm off)."""
PITCH_SPACINGS = 1.25
"""The scan grid's pitch in measured point spacings, at most: scans that overlap make the
spacing measured (√(area / points)) up to a fifth finer than the pitch of each."""
"""Why a section is unmeasured (``_unmeasured``), in the order they are checked…"""
SIDE_NO_TOP, SIDE_NO_EDGE, SIDE_PAST_HOLE, SIDE_NO_MODEL = range(1, 5)
DROPOUT_STRETCHES = 4.0
DROPOUT_SPACINGS = 2.0
"""A corner placed where its top's points stop, whose widest stretch near the top's end is
this many times its seam's typical one and this many spacings: points are missing there
(a dark or shiny patch at the edge), and the corner may lie anywhere in the dark — edge
sweep, dark patches at 0.1 mm: gaps 0.2–0.41 mm off with σ 0.115 (3.6σ)."""
"""…and, for SIDE, what is wrong with the side."""


@dataclass(frozen=True)
class SectionConfig:
    pitch_mm: float = SETTINGS["pitch_mm"].default
    slab_mm: float = SETTINGS["slab_mm"].default
    edge_band_mm: float = SETTINGS["edge_band_mm"].default
    """The top is fitted from this far inside its end (where it leaves the top by 3σ;
    a 10 mm arc leaves it 1.1 mm after its tangent point)."""
    top_band_mm: float = SETTINGS["top_band_mm"].default
    end_margin_mm: float = 3.0
    """Sections stop this far (plus the half band of the seams around) from a seam's ends,
    clear of crossing seams and the corners."""
    decision_sections: int = 5
    """Gap and step are judged against the tolerances on their running median over this
    many sections (10 mm at the default pitch)."""
    edge_model: str = SETTINGS["edge_model"].default
    """``auto``: each side's edge model chosen by the information criterion. ``square``,
    ``chamfer``, ``round``, ``free``: that model on every side (the user's choice, as in
    profile gap/flush tools). ``void``: the last measured point of each panel, what a
    single-profile gap gauge reports (the peer in ``vista defects bench``)."""
    gap_mode: str = SETTINGS["gap_mode"].default
    """``walls``: between the two side faces along the mean direction of the tops (the
    default). ``surface``: between the edge points along panel a's top (Gocator's
    "Surface" axis; its "Edge" axis is the same here, side faces being square to their
    tops). ``distance``: the straight distance between the two edge points — where each
    edge profile meets its side face (Gocator's "Distance"). ``sharp``: the straight
    distance between the virtual sharp edges, where each top meets its side face."""
    max_edge_depth_mm: float = 10.0
    """Points deeper than this below both tops are the backing, not an edge."""
    fit_gate: float = 1.5
    """A model whose truncated RMS residual exceeds this many σ does not explain the edge
    (with residuals truncated at 3σ, a sixth of the points off it already does that)."""
    max_edge_sigma_mm: float = 0.05
    """An edge placed with a larger 1σ uncertainty by the free fallback over points below
    the top that no model explains (a profile none describes) is not measured; with none
    beyond the top's end, it is, with the σ of any shape its points allow
    (``edges.bare_extent``)."""
    min_profiles: int = 10
    """A section's slab is at least this many point spacings thick (``slab_width_mm``;
    0: ``slab_mm`` whatever the spacing, as the single-profile gauge takes it)."""
    max_view_deg: float = SETTINGS["max_view_deg"].default
    """How far off the normal a view may have been: a square corner on the lower panel
    closer to the higher panel's edge than step × tan(this) may be in its shadow."""


@dataclass(frozen=True)
class EdgeShape:
    """One side of a seam: its edge model and its shape, along the whole seam."""

    model: str
    radius_mm: float | None = None
    angle_deg: float | None = None
    burr_mm: float = 0.0
    """Median height of a lip standing above the top at the edge (0: none)."""


@dataclass(frozen=True)
class SeamProfile:
    seam: SeamLine
    along_mm: np.ndarray
    """(K,) positions of all sections along the seam line."""
    gap_mm: np.ndarray
    """(K,) NaN where the section's gap is unmeasured."""
    step_mm: np.ndarray
    """(K,) NaN where a top could not be fitted."""
    gap_sigma_mm: np.ndarray
    """(K,) 1σ of each gap, from its two edges."""
    at_local: np.ndarray
    """(K, 3) (u, v, w) of each section's centre on the mean top."""
    normal_local: np.ndarray
    """(K, 3) mean top normal of each section in the surface frame."""
    models: np.ndarray
    """(K, 2) int: the edge model (``edges.MODELS``) used on side a and b."""
    residual_mm: np.ndarray
    """(K, 2) truncated RMS residual of each side's edge fit."""
    unmeasured: tuple[str | None, ...]
    """(K,) why a section's gap is not measured, or None."""
    edges: tuple[EdgeShape, EdgeShape]
    noise_mm: float
    """σ of the points about the panel tops, estimated along this seam."""
    sampling_mm: float
    """The median over its sides of the widest stretch between neighbouring points of a
    top near its end, seen across the seam (``edges.sampling``): how finely the slab's
    profiles together sample an edge; NaN where no side could tell."""
    sampling_mid_mm: float
    """The same from the middle half of each slab along the seam: as wide as
    ``sampling_mm`` where every profile crosses the edges at one phase, wider where their
    phase drifts along the seam (what a thicker slab would gain, ``measure``)."""


def slab_width_mm(config: SectionConfig, spacing_mm: float) -> float:
    """How thick a section's slab is: ``slab_mm``, or ``min_profiles`` point spacings
    where that is more. A coarse scan samples an edge a few times per profile;
    the profiles of a thicker slab cross it at other phases (the scan grid lies at an
    angle to the seam, or a line scanner's lines fall anywhere along it), so that together
    they sample it finely — a super-resolved edge — once each side's edge line is followed
    along the slab (``profile_seam``). Slabs thicker than the pitch overlap: neighbouring
    sections then share points, and their gaps their errors."""
    return max(config.slab_mm, config.min_profiles * spacing_mm)


FINEST_SPACING_MM = 0.1
"""A corner's place is trusted to what its profiles resolve together, and to no less
than the spacing or this, whichever is less (``resolved_mm``)."""


def resolved_mm(sampling_mm: np.ndarray, spacing_mm: float) -> np.ndarray:
    """(groups,) how finely each side's edge is resolved across: the widest stretch
    between its profiles' pooled points near the top's end (its ``sampling``), no less
    than the spacing where that is ``FINEST_SPACING_MM`` or less — two spacings of a fine
    cloud are what a gap between corners must exceed, as before pooling; a coarse
    cloud's thick slabs resolve more finely than its spacing — and the spacing where the
    sampling is unknown."""
    floor = min(spacing_mm, FINEST_SPACING_MM)
    return np.where(np.isfinite(sampling_mm), np.maximum(sampling_mm, floor), spacing_mm)


def top_jump_mm(spacing_mm: float) -> float:
    """The widest stretch without points that a top is followed across towards the gap:
    wider is a hole in the top, or the gap. A coarse cloud's profiles leave stretches of
    up to a spacing between neighbouring points."""
    return max(TOP_JUMP_MM, TOP_JUMP_SPACINGS * spacing_mm)


def reach_mm(seam: SeamLine, config: SectionConfig) -> float:
    """How far across its centre line a seam's sections take points: the band, the edge
    band and the top band on each side, and 1 mm to spare."""
    return seam.half_band_mm + config.edge_band_mm + config.top_band_mm + 1.0


def edge_reach_mm(seam: SeamLine, spacing_mm: float) -> float:
    """How far across its centre line a seam's edge zones reach: its band (where the tops
    end), the zone's start inside a top's end (``edges.band_far_mm``), and 1 mm to spare."""
    return seam.half_band_mm + edges.band_far_mm(spacing_mm) + 1.0


def section_range(
    seam: SeamLine, config: SectionConfig, *, end_margin_mm: float
) -> tuple[float, int]:
    """Position along the seam line of the first section, and how many there are."""
    first = seam.start_mm + end_margin_mm
    return first, int(np.floor((seam.end_mm - end_margin_mm - first) / config.pitch_mm)) + 1


@dataclass(frozen=True)
class _Edges:
    """Per group: where the side face stands (u, along the top from its end), the depth of
    the edge point below the top, the 1σ of X, the model used and its truncated RMS
    residual; whether the top continues past a hole, and whether X was placed on a side
    face a view saw; and the two sides' shapes."""

    x: np.ndarray
    depth: np.ndarray
    sigma: np.ndarray
    models: np.ndarray
    residual: np.ndarray
    past_hole: np.ndarray
    face_seen: np.ndarray
    gap_seen: np.ndarray
    """(groups,) whether views saw down into the gap beside the edge: points below its
    corner (or its foot) beyond it, or the backing (``GAP_SEEN_POINTS`` of them)."""
    unexplained: np.ndarray
    """(groups,) how wide the points below the top beyond a free edge run, which no model
    explains (0: none, or a model's edge)."""
    shapes: tuple[EdgeShape, EdgeShape]
    sampling: np.ndarray
    """(groups,) the widest stretch between the top's points near its end (NaN: too few)."""
    sampling_mid: np.ndarray
    """(groups,) the same from the points of the slab's middle half along the seam."""


@dataclass(frozen=True)
class _Tops:
    """Per group (2k + side, side b mirrored so its edge faces +xm): the top end in x,
    the plane α + β·xm + γ·y, and its noise."""

    end_x: np.ndarray
    plane: np.ndarray
    sigma: np.ndarray


def profile_seam(
    slab: np.ndarray,
    seam: SeamLine,
    config: SectionConfig,
    first: float,
    count: int,
    spacing_mm: float,
) -> SeamProfile | None:
    """Measure the ``count`` sections of ``seam`` from ``first`` on, given the points in
    their slabs as (4, M) rows (section k, y along from its plane, x across, height w;
    ``binning.seam_slabs``) and the cloud's point spacing."""
    k, y, x, w = slab[0].astype(np.int64), slab[1], slab[2], slab[3]
    groups = 2 * count
    outer = seam.half_band_mm + config.edge_band_mm
    rough, rough_sigma = _robust_plane(2 * k + (x > 0), x, w, y, -np.inf, np.inf, outer, groups)
    end_a, end_b, width = _widest_gaps(
        k, x, w, y, rough, seam.half_band_mm + 1.5, config.max_edge_depth_mm, count
    )
    found = (width > 0) & np.isfinite(rough).all(axis=1).reshape(count, 2).all(axis=1)
    middle = (end_a + end_b) / 2
    if config.edge_model == "void":
        end_x = np.stack([end_a, end_b], 1).ravel()
    else:
        jump = top_jump_mm(spacing_mm)
        end_x = _follow_tops(k, x, w, y, rough, rough_sigma, middle, outer, jump)
        if np.max(np.abs(y), initial=0.0) > config.slab_mm / 2:  # a thick slab
            x = x - _edge_slopes(end_x, config.pitch_mm)[2 * k + (x > middle[k])] * y
            end_x = _follow_tops(k, x, w, y, rough, rough_sigma, middle, outer, jump)
    group, xm = _mirror(k, x, middle, end_x)
    low, high = -config.edge_band_mm - config.top_band_mm, -config.edge_band_mm
    plane, sigma = _robust_plane(group, xm, w, y, low, high, 0.0, groups)
    tops = _Tops(end_x, plane, sigma)
    noise = float(np.nanmedian(sigma)) if np.isfinite(sigma).any() else np.nan
    fitted = _edges(group, xm, w, y, middle, tops, noise, spacing_mm, config, groups)
    return _sections(seam, config, first, count, spacing_mm, tops, found, noise, fitted)


def _edge_slopes(end_x: np.ndarray, pitch_mm: float) -> np.ndarray:
    """(groups,) how fast each side's top end moves across per mm along the seam: the
    slope of a line fitted to its sections' top ends (robustly: twice, without the ends
    beyond 3 robust σ of the first line), the same for every section of the side. The
    seam line found on the height map runs along the gap's middle to a fraction of a
    degree, and a tapered gap's edges leave it by their own slopes: in a slab several mm
    thick, either would smear an edge across its profiles by as much as a coarse
    spacing's resolution."""
    sections = len(end_x) // 2
    along = np.arange(sections) * pitch_mm
    slopes = np.zeros(2)
    for side in (0, 1):
        ends = end_x[side::2]
        keep = np.isfinite(ends)
        for _ in range(2):
            if keep.sum() < 3:
                break
            slope, offset = np.polyfit(along[keep], ends[keep], 1)
            residual = ends - (slope * along + offset)
            spread = 1.4826 * np.median(np.abs(residual[keep])) + 1e-6
            slopes[side] = slope
            keep = np.isfinite(ends) & (np.abs(residual) <= 3 * spread)
    return np.tile(slopes, sections)


@njit(cache=True, nogil=True)
def _robust_plane(
    group: np.ndarray,
    x: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    low: float,
    high: float,
    min_abs: float,
    groups: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Planes w = α + β·x + γ·y per group over the points with low ≤ x ≤ high and |x| ≥
    ``min_abs``: a least-squares fit to the points within ``START_WINDOW_MM`` of the
    group's median height (not the backing seen through a wide gap, nor spikes), then again
    without the points beyond 3σ of it (dents, strays). Returns ((groups, 3) planes,
    (groups,) σ), NaN where too few points.

    Per group: the 3 × 3 normal equations (Σ from ``_top_sums``, 1e-9·n added on the
    diagonal) solved by LAPACK as NumPy's batched solve does, and σ² = Σw²/n − (α·Σw +
    β·Σx·w + γ·Σy·w)/n (0 where that is not a number, as ``np.fmax`` gives it): each step
    in the order the NumPy version of this took, so the same values."""
    plane = np.zeros((groups, 3))
    plane[:, 0] = _median_heights(group, x, w, low, high, min_abs, groups)
    clip = np.full(groups, START_WINDOW_MM)
    sigma = np.empty(groups)
    normal, rhs = np.empty((3, 3)), np.empty(3)
    sums = np.zeros((10, groups))
    for _ in range(2):
        sums = _top_sums(group, x, w, y, low, high, min_abs, plane, clip, groups)
        for g in range(groups):
            s = sums[:, g]
            if s[0] >= MIN_POINTS:
                normal[0, 0], normal[0, 1], normal[0, 2] = s[0], s[1], s[2]
                normal[1, 0], normal[1, 1], normal[1, 2] = s[1], s[3], s[4]
                normal[2, 0], normal[2, 1], normal[2, 2] = s[2], s[4], s[5]
                for k in range(3):
                    normal[k, k] += 1e-9 * s[0]
                rhs[0], rhs[1], rhs[2] = s[6], s[7], s[8]
                plane[g] = np.linalg.solve(normal, rhs)
            else:
                plane[g] = np.nan
            n = max(s[0], 1.0)
            fitted = plane[g, 0] * s[6] + plane[g, 1] * s[7] + plane[g, 2] * s[8]
            variance = s[9] / n - (fitted / n if np.isfinite(fitted) else np.nan)
            sigma[g] = np.sqrt(variance if variance > 0 else 0.0)  # NaN too: np.fmax
            clip[g] = max(3.0 * sigma[g], 0.01) if np.isfinite(sigma[g]) else np.inf
            for k in range(3):
                if not np.isfinite(plane[g, k]):
                    plane[g, k] = 0.0
    for g in range(groups):
        if not sums[0, g] >= MIN_POINTS:
            plane[g] = np.nan
            sigma[g] = np.nan
    return plane, sigma


def _edges(
    group: np.ndarray,
    xm: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    middle: np.ndarray,
    tops: _Tops,
    noise: float,
    spacing_mm: float,
    config: SectionConfig,
    groups: int,
) -> _Edges:
    """Every side of every section: its edge model and where its side face stands."""
    sections = groups // 2
    if config.edge_model == "void":
        zero, no = np.zeros(groups), np.zeros(groups, bool)
        free = np.full(groups, edges.FREE)
        void = (EdgeShape("void"), EdgeShape("void"))
        none = np.full(groups, np.nan)
        return _Edges(zero, zero, zero, free, none, no, no, no, zero, void, none, none)
    gap_end = np.abs(np.repeat(middle, 2) - tops.end_x)
    starts, zu, zd, zy, deep = _edge_zones(
        group, xm, w, y, tops.plane, gap_end, config.max_edge_depth_mm, groups, spacing_mm
    )
    seam_sigma = max(noise, 0.005) if np.isfinite(noise) else 0.02
    sigma = np.fmax(tops.sigma, seam_sigma)  # the noise here, where more than the seam's

    def fit(models: np.ndarray, shape: np.ndarray) -> tuple:
        """``edges.fit_sides`` of the (groups, 4) ``models`` wanted on each side."""
        return edges.fit_sides(
            starts, zu, zd, sigma, spacing_mm, config.max_edge_depth_mm, models, shape
        )

    chosen, shape, shape_sigma, shapes = _choose_models(fit, np.diff(starts), config, groups)
    side_model = np.tile(chosen, sections)
    index = np.arange(groups)
    own = np.zeros((groups, 4), bool)
    own[index, side_model] = True  # each side its own model only…
    # …and the square corner's everywhere if a side has it: ``face_seen`` reads its flag
    # on every side that is not chamfered (a cheap fit, unlike a free arc).
    own[:, edges.SQUARE] |= edges.SQUARE in chosen
    fits, extra = fit(own, shape)
    best = fits[index, side_model]
    poor = ~np.isfinite(best[:, 2]) | ~(best[:, 5] <= config.fit_gate**2)
    models = side_model.copy()
    columns = edges.shape_columns(starts, zu, zd, sigma, spacing_mm)
    if poor.any() and config.edge_model == "auto":
        rescued = _another_model(fit, poor, shapes, fits, np.diff(starts), columns, config)
        models[poor] = rescued[poor]
    poor = models == edges.FREE
    unexplained = np.zeros(groups)
    if poor.any():  # the fallback, where no model explains the edge
        fallback, widths = fit(_wanted(poor, [edges.FREE]), shape)
        fits[poor, edges.FREE] = fallback[poor, edges.FREE]
        unexplained[poor] = widths[poor, 1]
    final = fits[index, models]
    sampling = edges.sampling_gaps(starts, zu, zd, sigma, spacing_mm)
    # The same from the slab's middle half: how much of that the slab's thickness gave.
    mid = np.abs(zy) <= np.max(np.abs(y), initial=0.0) / 2
    owner = np.repeat(np.arange(groups), np.diff(starts))
    mid_starts = np.concatenate([[0], np.cumsum(np.bincount(owner[mid], minlength=groups))])
    sampling_mid = edges.sampling_gaps(mid_starts, zu[mid], zd[mid], sigma, spacing_mm)
    # An arc or chamfer seen at too few places across is placed no finer than its points
    # — the model that fits them best may put the side face a whole stretch either way —
    # but an arc that spans two stretches or more, no finer than a chamfer that explains
    # them as well would place it (``_ambiguity``); either, seen at more, no finer than
    # ``SHAPE_PHASE`` of a stretch.
    shaped = np.isin(models, [edges.ROUND, edges.CHAMFER])
    stretch = np.nan_to_num(sampling, nan=spacing_mm)
    few = shaped & (columns < edges.SHAPE_COLUMNS)
    wide_arc = (models == edges.ROUND) & (final[:, 1] >= WIDE_ARC_STRETCHES * stretch)
    floor = np.maximum(
        np.where(few & ~wide_arc, 1 / np.sqrt(3.0), np.where(shaped, SHAPE_PHASE, 0.0)) * stretch,
        np.maximum(
            _ambiguity(fit, few & wide_arc, final[:, 2], shapes, config),
            np.where(models == edges.ROUND, ARC_FORM * np.nan_to_num(final[:, 1]), 0.0),
        ),
    )
    x = final[:, 2]
    depth = np.where(
        models == edges.ROUND,
        final[:, 1],
        np.where(models == edges.CHAMFER, (x - final[:, 0]) * np.tan(final[:, 1]), 0.0),
    )
    shapes = tuple(
        EdgeShape(
            edges.MODELS[chosen[s]],
            radius_mm=float(shape[s])
            if chosen[s] == edges.ROUND and np.isfinite(shape[s])
            else None,
            angle_deg=float(np.degrees(shape[s]))
            if chosen[s] == edges.CHAMFER and np.isfinite(shape[s])
            else None,
            burr_mm=float(np.median(extra[s::2, 0])) if sections else 0.0,
        )
        for s in (0, 1)
    )
    return _Edges(
        x=x,
        depth=depth,
        sigma=np.maximum(
            np.hypot(
                final[:, 3], np.where(models == edges.ROUND, np.tile(shape_sigma, sections), 0)
            ),
            floor,
        ),
        models=models,
        residual=np.sqrt(np.fmin(np.where(poor, best[:, 5], final[:, 5]), edges.TRUNCATION**2))
        * sigma,
        past_hole=_top_beyond(starts, zu, zd, sigma, x),
        face_seen=(np.where(side_model == edges.CHAMFER, extra[:, 3], extra[:, 2]) > 0)
        & (models == side_model),
        gap_seen=_gap_seen(starts, zu, zd, x, depth, sigma, deep),
        unexplained=unexplained,
        shapes=shapes,
        sampling=sampling,
        sampling_mid=sampling_mid,
    )


GAP_SEEN_POINTS = 3
"""Points below a corner beyond it that show a view saw down into the gap beside it (a
stray or two may lie anywhere)."""


def _gap_seen(
    starts: np.ndarray,
    zu: np.ndarray,
    zd: np.ndarray,
    x: np.ndarray,
    depth: np.ndarray,
    sigma: np.ndarray,
    deep: np.ndarray,
) -> np.ndarray:
    """(groups,) whether a view saw down into the gap beside each side's edge: its zone's
    points beyond X more than 3σ below its corner or foot (``depth``), and the backing
    beyond its top's end (``deep``), ``GAP_SEEN_POINTS`` or more. A ray that reached below
    the corner beside it passed the other panel's edge, and so did that view's rays to
    the corner: it was not in the other panel's shadow, whatever the step."""
    owner = np.repeat(np.arange(len(x)), np.diff(starts))
    below = (zu > x[owner]) & (zd > depth[owner] + 3 * sigma[owner])
    return np.bincount(owner[below], minlength=len(x)) + deep >= GAP_SEEN_POINTS


def _choose_models(
    fit: Callable, points: np.ndarray, config: SectionConfig, groups: int
) -> tuple[tuple[int, int], np.ndarray, list[float], np.ndarray]:
    """Each side's model and shape, from ``SELECTION_SECTIONS`` sections spread along the
    seam: every model fitted freely there; the shape (radius, angle) taken as the median,
    since it belongs to the edge; the models fitted again with it and compared
    (``_choose``). Returns the two models, the shape per group, each side's 1σ of the
    radius (a wrong ρ moves X = u_c + ρ), and every model's shape per group ((4, groups),
    NaN where it has none)."""
    if config.edge_model == "auto":
        candidates = [edges.SQUARE, edges.CHAMFER, edges.ROUND, edges.FREE]
    else:
        candidates = [edges.MODELS.index(config.edge_model)]
    stride = max(1, (groups // 2) // SELECTION_SECTIONS)
    trial_sections = (np.arange(groups) // 2) % stride == 0
    free, _ = fit(_wanted(trial_sections, candidates), np.full(groups, np.nan))
    shapes = np.full((4, groups), np.nan)
    for model in (edges.CHAMFER, edges.ROUND):
        for s in (0, 1):
            values = free[s::2, model, 1][trial_sections[s::2]]
            values = values[np.isfinite(values)]
            if len(values):
                shapes[model, s::2] = np.median(values)
    trial = free.copy()
    for model in (edges.CHAMFER, edges.ROUND):
        if model in candidates:
            trial[:, model] = fit(_wanted(trial_sections, [model]), shapes[model])[0][:, model]
    wanted = np.zeros(4, bool)
    wanted[candidates] = True
    chosen = _choose(trial[trial_sections], np.maximum(points, 1)[trial_sections], wanted)
    radius_sigma = [0.0, 0.0]
    for s in (0, 1):
        if chosen[s] == edges.ROUND:
            radii = free[s::2, edges.ROUND, 1][trial_sections[s::2]]
            radius_sigma[s] = _median_sigma(radii[np.isfinite(radii)])
    shape = np.where(np.arange(groups) % 2 == 0, shapes[chosen[0]], shapes[chosen[1]])
    return (chosen[0], chosen[1]), shape, radius_sigma, shapes


def _another_model(
    fit: Callable,
    poor: np.ndarray,
    shapes: np.ndarray,
    fits: np.ndarray,
    points: np.ndarray,
    columns: np.ndarray,
    config: SectionConfig,
) -> np.ndarray:
    """(groups,) for each ``poor`` side (its seam's model does not explain its points), the
    other shaped model that does — a chamfer or an arc — where points lie below its top
    (``columns``), with the least information criterion (cost + ln n per parameter of the
    section); ``edges.FREE`` where none does. Their fits are written into ``fits``. A
    coarse grid along a seam samples an edge at a few places, the same in every section:
    three points on a round edge's curve at 0.75 mm, which the seam's chamfer could not
    follow, left half the seam's sections unmeasured."""
    tried = np.full((len(poor), 4), np.inf)
    poor = poor & (columns > 0)
    for model in (edges.CHAMFER, edges.ROUND):
        for shape, trial, explains in _explaining(fit, poor, model, shapes, config):
            parameters = edges.LOCAL_PARAMETERS[model] + ~np.isfinite(shape)
            criterion = trial[:, 4] + parameters * np.log(np.maximum(points, 1))
            better = explains & (criterion < tried[:, model])
            fits[better, model] = trial[better]
            tried[better, model] = criterion[better]
    best = np.argmin(tried, axis=1)
    return np.where(np.isfinite(tried[np.arange(len(poor)), best]), best, edges.FREE)


def _ambiguity(
    fit: Callable, few: np.ndarray, x: np.ndarray, shapes: np.ndarray, config: SectionConfig
) -> np.ndarray:
    """(groups,) 1σ that covers a chamfer where it explains as well the points of a round
    side (its wide arc seen at ``few`` places across): half the distance between the side
    faces the two place (0 where no chamfer explains them). One or two columns of a coarse
    grid on an edge, and a chamfer fits as an arc does (a 1 mm chamfer at 0.5 mm, rows
    along the seam, fitted as an arc 0.38 mm off with σ 0.024 mm); yet where no chamfer
    can follow them, the arc's radius, shared along the seam, pins the edge (a 1.6 mm
    arc at 0.6 mm spacing, one or two columns on it: a floor of the stretch / √3 gave σ
    0.42 mm on errors of 0.05)."""
    out = np.zeros(len(few))
    for _, trial, explains in _explaining(fit, few, edges.CHAMFER, shapes, config):
        out[explains] = np.maximum(out[explains], np.abs(trial[explains, 2] - x[explains]) / 2)
    return out


def _explaining(
    fit: Callable, sides: np.ndarray, model: int, shapes: np.ndarray, config: SectionConfig
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``model`` fitted on ``sides`` with the shape the seam's sections gave it, then with
    its own: per try, (the shape, the (groups, FIELDS) fits, where the fit explains the
    points: within the gate). Nothing is fitted where no side is asked."""
    tries = []
    for shape in (shapes[model], np.full(len(sides), np.nan)):
        if not sides.any():
            break
        trial = fit(_wanted(sides, [model]), shape)[0][:, model]
        explains = sides & np.isfinite(trial[:, 2]) & (trial[:, 5] <= config.fit_gate**2)
        tries.append((shape, trial, explains))
    return tries


def _wanted(sides: np.ndarray, models: list[int]) -> np.ndarray:
    """(groups, 4) bool for ``edges.fit_sides``: ``models`` on the ``sides`` (bool per
    group), nothing elsewhere."""
    wanted = np.zeros((len(sides), 4), bool)
    wanted[np.ix_(sides, models)] = True
    return wanted


def _median_sigma(values: np.ndarray) -> float:
    """1σ of the median of ``values`` (robust: from their MAD)."""
    if len(values) < 2:
        return 0.0
    mad = 1.4826 * np.median(np.abs(values - np.median(values)))
    return float(1.25 * mad / np.sqrt(len(values)))


def _choose(fits: np.ndarray, n: np.ndarray, wanted: np.ndarray) -> list[int]:
    """Each side's model: the least information criterion over its (trial) sections — the
    truncated costs summed, plus ln n̄ for each parameter: per section (square: X; round:
    u_c; chamfer: u_c and its foot) and once per edge (the shared radius or angle). Where a
    chamfer or an arc could not be fitted (no points below the top) it costs what the
    square corner costs: it would fit no better."""
    chosen = []
    for s in (0, 1):
        side = fits[s::2]
        log_n = float(np.log(np.mean(n[s::2]))) if len(n[s::2]) else 0.0
        square = side[:, edges.SQUARE, 4]
        usable = np.isfinite(square) if wanted[edges.SQUARE] else np.ones(len(side), bool)
        totals = []
        for model in (edges.SQUARE, edges.CHAMFER, edges.ROUND):
            if not wanted[model] or not usable.any():
                totals.append(np.inf)
                continue
            cost = side[:, model, 4]
            if model != edges.SQUARE and wanted[edges.SQUARE]:
                cost = np.where(np.isfinite(cost), cost, square)
            parameters = (
                edges.LOCAL_PARAMETERS[model] * usable.sum() + edges.SHARED_PARAMETERS[model]
            )
            totals.append(float(np.nansum(cost[usable])) + parameters * log_n)
        chosen.append(int(np.argmin(totals)) if np.isfinite(min(totals)) else edges.FREE)
    return chosen


@njit(cache=True, nogil=True)
def _top_beyond(
    starts: np.ndarray, u: np.ndarray, d: np.ndarray, sigma: np.ndarray, edge_x: np.ndarray
) -> np.ndarray:
    """Per side: whether its top continues past the edge placed (≥ 3 points at top height
    more than 0.15 mm beyond X): the top's end was cut short by a hole."""
    out = np.zeros(starts.shape[0] - 1, np.bool_)
    for g in range(starts.shape[0] - 1):
        if not np.isfinite(edge_x[g]):
            continue
        beyond = 0
        for i in range(starts[g], starts[g + 1]):
            if abs(d[i]) < 3.0 * sigma[g] and u[i] > edge_x[g] + 0.15:
                beyond += 1
        out[g] = beyond >= 3
    return out


def _sections(
    seam: SeamLine,
    config: SectionConfig,
    first: float,
    count: int,
    spacing_mm: float,
    tops: _Tops,
    found: np.ndarray,
    noise: float,
    fitted: _Edges,
) -> SeamProfile:
    """Gap, step, uncertainty and self-checks of every section, from its tops and edges."""
    edge_x = fitted.x
    alpha, beta = tops.plane[:, 0], tops.plane[:, 1]
    norm = np.sqrt(1 + beta**2)
    side = np.arange(2 * count) % 2

    def point(depth: np.ndarray) -> np.ndarray:
        """(groups, 2) section (x, w) of each side's edge point ``depth`` below its top."""
        xm = (edge_x + beta * depth) / norm
        return np.stack(
            [
                np.where(side == 0, tops.end_x + xm, tops.end_x - xm),
                alpha + beta * xm - depth * norm,
            ],
            1,
        )

    sharp, deep = point(np.zeros_like(edge_x)), point(fitted.depth)
    na, nb, ba, bb = norm[0::2], norm[1::2], beta[0::2], beta[1::2]
    tau = np.stack([1 / na + 1 / nb, ba / na - bb / nb], 1)
    tau /= np.linalg.norm(tau, axis=1, keepdims=True)
    if config.gap_mode == "walls":
        gap = np.sum((sharp[1::2] - sharp[0::2]) * tau, axis=1)
    elif config.gap_mode == "surface":
        gap = np.sum((deep[1::2] - deep[0::2]) * np.stack([1 / na, ba / na], 1), axis=1)
    elif config.gap_mode == "distance":
        gap = np.linalg.norm(deep[1::2] - deep[0::2], axis=1)
    else:
        gap = np.linalg.norm(sharp[1::2] - sharp[0::2], axis=1)
    end_a, end_b = tops.end_x[0::2], tops.end_x[1::2]
    mid = (sharp[0::2, 0] + sharp[1::2, 0]) / 2
    mid = np.where(np.isfinite(mid), mid, (end_a + end_b) / 2)
    wa = alpha[0::2] + ba * (mid - end_a)
    wb = alpha[1::2] + bb * (end_b - mid)
    step = np.where(found, (wb - wa) * tau[:, 0], np.nan)
    gap_sigma = _gap_sigma(fitted.sigma, fitted.sampling, spacing_mm)
    if config.edge_model == "void":  # the gauge: a number wherever it sees a gap
        reasons = [None if f else "no gap seen between the panels" for f in found]
    else:
        reasons = _unmeasured(gap, step, found, tops, fitted, noise, spacing_mm, config)
    gap = np.where([r is None for r in reasons], gap, np.nan)
    positions = first + np.arange(count) * config.pitch_mm
    if config.edge_model != "void":
        departing = _departing(gap, gap_sigma, positions, fitted.models.reshape(count, 2))
        for i in np.flatnonzero(departing):
            reasons[i] = (
                f"an edge fits no model and the gap ({gap[i]:.3f} mm) departs from the line "
                "of the seam's other sections by more than their spread allows (another edge "
                "in its slab?)"
            )
        gap = np.where(departing, np.nan, gap)
    across = np.where(np.isfinite(mid), mid, 0.0)
    at_uv = seam.point_uv(positions) + np.multiply.outer(across, seam.across_uv)
    at = np.column_stack([at_uv, (wa + wb) / 2])
    tau = np.where(np.isfinite(tau), tau, [[1.0, 0.0]])
    normal_2d = np.stack([-tau[:, 1], tau[:, 0]], 1)
    normal = np.column_stack([np.multiply.outer(normal_2d[:, 0], seam.across_uv), normal_2d[:, 1]])
    return SeamProfile(
        seam,
        positions,
        gap,
        step,
        gap_sigma,
        at,
        normal,
        fitted.models.reshape(count, 2),
        fitted.residual.reshape(count, 2),
        tuple(reasons),
        fitted.shapes,
        noise,
        _median(fitted.sampling),
        _median(fitted.sampling_mid),
    )


DEPARTURE_SIGMAS = 5.0


def _departing(
    gap: np.ndarray, sigma: np.ndarray, along: np.ndarray, models: np.ndarray
) -> np.ndarray:
    """(K,) sections placed by the free fallback on a side (no model explains its edge)
    whose gap departs from the line the seam's modelled sections fit by more than
    ``DEPARTURE_SIGMAS`` of their σ and that line's spread together: the fallback took
    another edge in its slab. (At the end of a seam meeting a junction, rows along it,
    seven such sections read gaps 1.5–2.3 mm too wide with σ 0.076.)"""
    measured = np.isfinite(gap)
    modelled = measured & (models != edges.FREE).all(axis=1)
    free = measured & ~modelled
    if modelled.sum() < 3 or not free.any():
        return np.zeros(len(gap), bool)
    # Theil–Sen: a few modelled sections far off (at a seam's end) do not move the line
    a, g = along[modelled], gap[modelled]
    i, j = np.triu_indices(len(a), 1)
    slope = float(np.median((g[j] - g[i]) / (a[j] - a[i])))
    offset = float(np.median(g - slope * a))
    residual = gap - (slope * along + offset)
    spread = 1.4826 * float(np.median(np.abs(residual[modelled] - np.median(residual[modelled]))))
    return free & (np.abs(residual) > DEPARTURE_SIGMAS * np.hypot(sigma, spread))


SHARED_PHASE_SPACINGS = (0.5, 0.9)
"""Two corners sampled by profiles that leave stretches of 0.9 spacings or more share the
scan's phase; of 0.5 or less, their pooled phases are dense and their errors independent
(``_gap_sigma``; in between, in proportion)."""


def _gap_sigma(sigma: np.ndarray, sampling: np.ndarray, spacing_mm: float) -> np.ndarray:
    """(sections,) 1σ of each gap from its two sides' (``sigma``, per group): independent
    errors add in quadrature, but two corners placed from profiles that sample both at one
    phase err together — a seam whose gap tapers at rows along it: its edges cross the
    lattice's points together, and the gap's error ran evenly from −s to +s along it
    (σ s/√3, where quadrature gives s/√6: 0.78–0.87 of such a seam's sections within 2σ).
    The correlation grows from 0 to 1 as the sides' pooled stretch (``sampling``) grows
    over ``SHARED_PHASE_SPACINGS``."""
    a, b = sigma[0::2], sigma[1::2]
    low, high = SHARED_PHASE_SPACINGS
    stretch = np.fmin(sampling[0::2], sampling[1::2]) / spacing_mm
    shared = np.clip((np.nan_to_num(stretch, nan=0.0) - low) / (high - low), 0.0, 1.0)
    return np.sqrt(a * a + b * b + 2 * shared * a * b)


def _median(values: np.ndarray) -> float:
    """The median of the finite ``values``; NaN where there are none."""
    return float(np.nanmedian(values)) if np.isfinite(values).any() else np.nan


def _unmeasured(
    gap: np.ndarray,
    step: np.ndarray,
    found: np.ndarray,
    tops: _Tops,
    fitted: _Edges,
    noise: float,
    spacing_mm: float,
    config: SectionConfig,
) -> list[str | None]:
    """Why each section's gap cannot be trusted (None: it can). The first that holds, in
    this order: no gap seen; a side (a before b) without a top fit, without an edge, with
    its top going on past a hole, or whose edge no model explains; the edges crossing; a
    gap under twice what the profiles resolve (``resolved_mm``), or under the scan's pitch
    (``PITCH_SPACINGS``), at a corner placed by the points' extent; the lower panel's
    corner possibly in the higher one's shadow. Decided
    for all sections at once; the words are written for the sections left unmeasured
    only."""
    count = len(gap)
    models = fitted.models
    typical = np.nanmedian(fitted.sampling) if np.isfinite(fitted.sampling).any() else np.nan
    with np.errstate(invalid="ignore"):
        dropout = (
            np.isin(models, (edges.SQUARE, edges.CHAMFER, edges.FREE))
            & ~fitted.face_seen
            & (fitted.sampling > DROPOUT_STRETCHES * typical)
            & (fitted.sampling > DROPOUT_SPACINGS * spacing_mm)
        )
    side_reason = np.select(
        [
            ~np.isfinite(tops.plane[:, 0]),
            ~np.isfinite(fitted.x),
            fitted.past_hole | dropout,
            (models == edges.FREE)
            & (fitted.unexplained > 0)
            & ~(fitted.sigma <= config.max_edge_sigma_mm),
        ],
        [SIDE_NO_TOP, SIDE_NO_EDGE, SIDE_PAST_HOLE, SIDE_NO_MODEL],
        0,
    ).reshape(count, 2)
    side_b = side_reason[:, 0] == 0  # side a's reason, if it has one, comes first
    side = np.where(side_b, side_reason[:, 1], side_reason[:, 0])
    # Edges placed where their points stop (not pinned by an arc's shape or a side face).
    extent_based = (
        np.isin(models, (edges.SQUARE, edges.CHAMFER, edges.FREE)) & ~fitted.face_seen
    ).reshape(count, 2)
    shadow_mm = np.abs(step) * np.tan(np.radians(config.max_view_deg))
    lower = np.where(step > 0, 0, 1)  # the side of the lower panel
    resolved = resolved_mm(fitted.sampling, spacing_mm).reshape(count, 2).max(axis=1)
    with np.errstate(invalid="ignore"):
        crossing = gap < 0
        # …and under a grid pitch, which the scan rows skip over long stretches (panels a
        # coarse scan merged): their few crossings place such corners no better.
        least = np.maximum(2 * resolved, PITCH_SPACINGS * spacing_mm)
        narrow = (gap < least) & extent_based.any(axis=1)
        shadowed = (
            (np.abs(step) > 3 * noise)
            & ~fitted.face_seen.reshape(count, 2).any(axis=1)
            & ~fitted.gap_seen.reshape(count, 2)[np.arange(count), lower]
            & extent_based[np.arange(count), lower]
            & (gap < shadow_mm + resolved)  # within what the corners are placed to
        )
    reason = np.select(
        [~found, side > 0, crossing, narrow, shadowed],
        [NO_GAP, SIDE, CROSSING, NARROW, SHADOW],
        0,
    )
    names = ("a", "b")

    def words(i: int) -> str:
        if reason[i] == NO_GAP:
            return "no gap seen between the panels"
        if reason[i] == CROSSING:
            return f"the edges cross (gap {gap[i]:.3f} mm) and no overlap of the panels is seen"
        if reason[i] == NARROW:
            return (
                f"gap {gap[i]:.3f} mm is under twice what the profiles resolve, or the "
                f"scan's pitch ({least[i]:.2f} mm), at a corner: not resolved"
            )
        if reason[i] == SHADOW:
            low = lower[i]
            return (
                f"panel {names[low]}'s edge may lie in panel {names[1 - low]}'s shadow "
                f"(step {abs(step[i]):.2f} mm: a view {config.max_view_deg:g}° off the "
                f"normal hides {shadow_mm[i]:.2f} mm beyond its edge)"
            )
        name, g = names[int(side_b[i])], 2 * i + int(side_b[i])
        if side[i] == SIDE_NO_TOP:
            return (
                f"too few points on panel {name}'s top {config.edge_band_mm:g}–"
                f"{config.edge_band_mm + config.top_band_mm:g} mm from its edge"
            )
        if side[i] == SIDE_NO_EDGE:
            return f"too few points at panel {name}'s edge to place it"
        if side[i] == SIDE_PAST_HOLE:
            return (
                f"panel {name}'s top continues past a hole at its edge, or its points stop "
                "short of it (dark or shiny surface?)"
            )
        return (
            f"panel {name}'s edge fits no model: residual {fitted.residual[g]:.3f} mm > "
            f"{config.fit_gate:g}σ ({config.fit_gate * noise:.3f} mm)"
        )

    reasons: list[str | None] = [None] * count
    for i in np.flatnonzero(reason):
        reasons[i] = words(int(i))
    return reasons


@njit(cache=True, nogil=True)
def _top_sums(
    group: np.ndarray,
    xm: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    low: float,
    high: float,
    min_abs: float,
    plane: np.ndarray,
    clip: np.ndarray,
    groups: int,
) -> np.ndarray:
    """Per group, the normal equations of the plane w = α + β·xm + γ·y through the points
    with ``low`` ≤ xm ≤ ``high``, |xm| ≥ ``min_abs``, within ``clip`` of ``plane``:
    (10, groups) rows Σ1, Σxm, Σy, Σxm², Σxm·y, Σy², Σw, Σxm·w, Σy·w, Σw²."""
    sums = np.zeros((10, groups))
    for i in range(group.shape[0]):
        x = xm[i]
        if not low <= x <= high or abs(x) < min_abs:
            continue
        k, b, h = group[i], y[i], w[i]
        if k < 0 or abs(h - plane[k, 0] - plane[k, 1] * x - plane[k, 2] * b) >= clip[k]:
            continue
        sums[0, k] += 1.0
        sums[1, k] += x
        sums[2, k] += b
        sums[3, k] += x * x
        sums[4, k] += x * b
        sums[5, k] += b * b
        sums[6, k] += h
        sums[7, k] += x * h
        sums[8, k] += b * h
        sums[9, k] += h * h
    return sums


@njit(cache=True, nogil=True)
def _median_heights(
    group: np.ndarray,
    x: np.ndarray,
    w: np.ndarray,
    low: float,
    high: float,
    min_abs: float,
    groups: int,
) -> np.ndarray:
    """Per group, the median w of the points with low ≤ x ≤ high and |x| ≥ ``min_abs``,
    of every ``MEDIAN_STRIDE``-th point (a start for the fit needs no more; 0 where none)."""
    counts = np.zeros(groups + 1, np.int64)
    for i in range(0, group.shape[0], MEDIAN_STRIDE):
        if group[i] >= 0 and low <= x[i] <= high and abs(x[i]) >= min_abs:
            counts[group[i] + 1] += 1
    starts = np.cumsum(counts)
    values = np.empty(starts[-1])
    fill = starts[:-1].copy()
    for i in range(0, group.shape[0], MEDIAN_STRIDE):
        if group[i] >= 0 and low <= x[i] <= high and abs(x[i]) >= min_abs:
            values[fill[group[i]]] = w[i]
            fill[group[i]] += 1
    medians = np.zeros(groups)
    for g in range(groups):
        if starts[g + 1] > starts[g]:
            medians[g] = np.median(values[starts[g] : starts[g + 1]])
    return medians


@njit(cache=True, nogil=True)
def _widest_gaps(
    k: np.ndarray,
    x: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    rough: np.ndarray,
    reach: float,
    max_depth: float,
    count: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per section k, the widest stretch between consecutive points along x among those
    within ``reach`` of the centre line and less than ``max_depth`` below the lower of the
    two provisional tops (``rough``, unmirrored planes of groups 2k, 2k + 1): its two ends
    and its width (−1 with fewer than two points)."""
    near = np.zeros(k.shape[0], np.bool_)
    starts = np.zeros(count + 1, np.int64)
    for i in range(k.shape[0]):
        if abs(x[i]) >= reach:
            continue
        a, b = rough[2 * k[i]], rough[2 * k[i] + 1]
        top = min(a[0] + a[1] * x[i] + a[2] * y[i], b[0] + b[1] * x[i] + b[2] * y[i])
        if w[i] >= top - max_depth:
            near[i] = True
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
        end_a[s], end_b[s], width[s] = _widest_gap(xs[starts[s] : starts[s + 1]])
    return end_a, end_b, width


@njit(cache=True, nogil=True)
def _widest_gap(xs: np.ndarray) -> tuple[float, float, float]:
    """(left end, right end, width) of the widest stretch between consecutive values of
    ``xs`` in sorted order, the first (leftmost) of equals; (0, 0, −1) with fewer than two.

    Without sorting (the classic maximum-gap bucketing): n values over [lo, hi] fall into
    n − 1 buckets of (hi − lo) / (n − 1), which no widest stretch is shorter than, so it
    runs from one bucket's largest value to the next filled bucket's smallest. Should a
    bucket span as much (values spaced evenly to the last bit), the values are sorted
    instead: the same answer either way."""
    n = xs.shape[0]
    if n < 2:
        return 0.0, 0.0, -1.0
    lo, hi = xs.min(), xs.max()
    if hi == lo:
        return lo, lo, 0.0
    size = (hi - lo) / (n - 1)
    smallest, largest = np.full(n - 1, np.inf), np.full(n - 1, -np.inf)
    for x in xs:
        b = min(int((x - lo) / size), n - 2)
        smallest[b], largest[b] = min(smallest[b], x), max(largest[b], x)
    end_a = end_b = 0.0
    width, previous, span = -1.0, largest[0], largest[0] - smallest[0]
    for b in range(1, n - 1):
        if smallest[b] > largest[b]:
            continue  # empty
        if smallest[b] - previous > width:
            width, end_a, end_b = smallest[b] - previous, previous, smallest[b]
        previous, span = largest[b], max(span, largest[b] - smallest[b])
    if span < width:
        return end_a, end_b, width
    ordered = np.sort(xs)
    width = -1.0
    for j in range(n - 1):
        if ordered[j + 1] - ordered[j] > width:
            width = ordered[j + 1] - ordered[j]
            end_a, end_b = ordered[j], ordered[j + 1]
    return end_a, end_b, width


FOLLOW_BIN_MM = 0.025


@njit(cache=True, nogil=True)
def _follow_tops(
    k: np.ndarray,
    x: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    rough: np.ndarray,
    rough_sigma: np.ndarray,
    middle: np.ndarray,
    start: float,
    jump_mm: float,
) -> np.ndarray:
    """Per group (2k + side), the x where its top ends: its points within 3σ of the
    provisional top (``rough``, unmirrored), followed from the one nearest the far band's
    edge (|x| = ``start`` from the seam line; the farthest if the top ends before it)
    towards the gap, up to a jump wider than ``jump_mm`` or the gap's middle.
    Distances run outwards from each section's gap middle (the seam line, from the height
    map, can lie off it where one side's edge is not seen), binned every
    ``FOLLOW_BIN_MM`` (the end is exact: the nearest point of the last bin reached)."""
    groups = 2 * middle.shape[0]
    reach = start + 1.0 + np.abs(middle)  # the band's edge, from the middle
    bins = int(np.max(reach) / FOLLOW_BIN_MM) + 1 if groups else 1
    nearest = np.full((groups, bins), np.inf)  # per bin, the smallest distance seen
    beyond = np.full(groups, np.inf)  # a wide edge's top ends beyond the band: its end
    for i in range(k.shape[0]):
        side = 1 if x[i] > middle[k[i]] else 0
        g = 2 * k[i] + side
        p = rough[g]
        limit = 3.0 * max(rough_sigma[g], 0.005)
        if not abs(w[i] - p[0] - p[1] * x[i] - p[2] * y[i]) < limit:
            continue
        distance = x[i] - middle[k[i]] if side else middle[k[i]] - x[i]
        edge = start + 1.0 - middle[k[i]] if side else start + 1.0 + middle[k[i]]
        if distance > edge:
            beyond[g] = min(beyond[g], distance)
            continue
        nearest[g, int(distance / FOLLOW_BIN_MM)] = min(
            nearest[g, int(distance / FOLLOW_BIN_MM)], distance
        )
    ends = np.full(groups, np.nan)
    jump = int(jump_mm / FOLLOW_BIN_MM)
    for g in range(groups):
        row = nearest[g]
        top = bins - 1
        while top >= 0 and not np.isfinite(row[top]):
            top -= 1
        centre = middle[g // 2]
        if top < 0:
            if np.isfinite(beyond[g]):  # only beyond the band: a wide edge
                ends[g] = centre - beyond[g] if g % 2 == 0 else centre + beyond[g]
            continue
        end, empty = row[top], 0
        for b in range(top - 1, -1, -1):
            if np.isfinite(row[b]):
                end, empty = row[b], 0
            else:
                empty += 1
                if empty > jump:
                    break
        ends[g] = centre - end if g % 2 == 0 else centre + end
    return ends


@njit(cache=True, nogil=True)
def _mirror(
    k: np.ndarray, x: np.ndarray, middle: np.ndarray, end_x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's group (2k + side; −1 where its top end is unknown) and its xm: the
    distance past its side's top end towards the gap (side b mirrored)."""
    group = np.empty(k.shape[0], np.int64)
    xm = np.empty(k.shape[0])
    for i in range(k.shape[0]):
        side = 1 if x[i] > middle[k[i]] else 0
        g = 2 * k[i] + side
        end = end_x[g]
        if not np.isfinite(end):
            group[i], xm[i] = -1, np.nan
            continue
        group[i] = g
        xm[i] = end - x[i] if side else x[i] - end
    return group, xm


@njit(cache=True, nogil=True)
def _edge_zones(
    group: np.ndarray,
    xm: np.ndarray,
    w: np.ndarray,
    y: np.ndarray,
    plane: np.ndarray,
    gap_end: np.ndarray,
    max_depth: float,
    groups: int,
    spacing_mm: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points of each side's edge zone in its top's frame, in CSR order: (starts,
    u along the top towards the gap, δ below it, y along the seam). The zone runs from
    ``edges.ZONE_BACK_MM`` (or the sampling band's start, if further) inside the top end
    to the gap's middle (``gap_end`` past the top end), above ``max_depth``; and per side,
    how many points lie deeper beyond its top's end, up to the gap's middle, along the top
    (the backing a view saw through the gap beside it: in the surface frame, tilted to the
    tops of a stepped seam, a point 15 mm down lies some tenths of a mm aside)."""
    back = max(edges.ZONE_BACK_MM, edges.band_far_mm(spacing_mm))
    u = np.empty(group.shape[0])
    d = np.empty(group.shape[0])
    counts = np.zeros(groups + 1, np.int64)
    deep = np.zeros(groups, np.int64)
    for i in range(group.shape[0]):
        g = group[i]
        u[i] = np.nan
        if g < 0 or not -back - 0.5 < xm[i] <= gap_end[g]:
            continue
        alpha, beta, gamma = plane[g, 0], plane[g, 1], plane[g, 2]
        norm = np.sqrt(1.0 + beta * beta)
        flat = w[i] - gamma * y[i]
        ui = (xm[i] + beta * (flat - alpha)) / norm
        di = (alpha + beta * xm[i] - flat) / norm
        if 0.0 < ui <= gap_end[g] and di >= max_depth:
            deep[g] += 1
        if ui > -back and di < max_depth:
            u[i], d[i] = ui, di
            counts[g + 1] += 1
    starts = np.cumsum(counts)
    zu = np.empty(starts[-1])
    zd = np.empty(starts[-1])
    zy = np.empty(starts[-1])
    fill = starts[:-1].copy()
    for i in range(group.shape[0]):
        if np.isfinite(u[i]):
            g = group[i]
            zu[fill[g]], zd[fill[g]], zy[fill[g]] = u[i], d[i], y[i]
            fill[g] += 1
    return starts, zu, zd, zy, deep
