"""Edge models: where a panel's top ends and its side face stands, in one side of a section.

Each side is seen in its own frame: u along its top towards the gap (mm, 0 at the top's
last point), δ the depth below the top (mm, down is positive). The points of its edge zone
(from 2 mm inside the top's end to the middle of the gap) are explained by one of:

    square   the top runs to the corner (X, 0); the side face u = X below it
    chamfer  the top to (u_c, 0), a straight face down at angle α to (X, (X − u_c)·tan α),
             then the side face
    round    the top to (u_c, 0), a quarter circle of radius ρ (0.1–10 mm) down to
             (u_c + ρ, ρ), then the side face u = X = u_c + ρ
    free     no model: the edge is where the top ends (the fallback, see below)

X, where the side face stands, is what the gap is measured from. A rounded edge pins X by
its shape (the arc's tangent construction) even where the side face is not seen. A square
corner or a chamfer's foot is a place where the visible points stop, so X comes from their
*extent*: the last point plus the mean distance from a last sample to an edge, from the
sampling's own gaps (right whatever the sampling phase, unlike "the last point" or "half
the spacing"), or from the side face's points where a view sees them.

The model is chosen by an information criterion (BIC with a known noise σ and a truncated
quadratic loss — Gaussian inliers, outliers at a fixed cost): cost = Σ min(r²/σ², c²) +
k·ln n with k the model's parameters — per section (square 1, round 1, chamfer 2) and per
edge (the radius or the angle, shared along the seam). ``free`` is not in
the criterion: it is the fallback where the best model's fit is poor (truncated RMS >
``gate``·σ), and its X's uncertainty covers the unexplained points beyond the top's end.

All passes are compiled (numba) over the sides' points in CSR order (``starts``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

MODELS = ("square", "chamfer", "round", "free")
SQUARE, CHAMFER, ROUND, FREE = range(4)
LOCAL_PARAMETERS = np.array([1.0, 2.0, 1.0, 0.0])
"""Parameters each section fits: square X; chamfer u_c and its foot; round u_c."""
SHARED_PARAMETERS = np.array([0.0, 1.0, 1.0, 0.0])
"""Parameters an edge shares along its seam: the chamfer's angle, the arc's radius."""
TRUNCATION = 3.0
"""Residuals beyond this many σ are outliers (spikes, mixed pixels) at a fixed cost."""
ZONE_BACK_MM = 1.5
"""The edge zone starts this far inside the top's last point (a 10 mm arc leaves the top
within 1.1 mm of it at σ 0.02 mm)."""
EXTENT_BAND_MM = (1.5, 0.2)
"""The extent rule learns the sampling from the top's points 1.5 to 0.2 mm inside its last
point…"""
BAND_SPACINGS = 4.0
"""…or from this many point spacings inside it, where that is further: the band must hold
several of a coarse grid's columns (a grid along the seam puts every profile's points at
the same few u)."""


@njit(cache=True, nogil=True)
def band_far_mm(spacing: float) -> float:
    """How far inside the top's last point the sampling band (and the edge zone) begins."""
    return max(EXTENT_BAND_MM[0], BAND_SPACINGS * spacing)


MIN_RADIUS_MM, MAX_RADIUS_MM = 0.1, 10.0
MIN_ANGLE, MAX_ANGLE = np.radians(10.0), np.radians(80.0)
MIN_EDGE_POINTS = (6, 2)
"""A chamfer or an arc needs this many points below the top to be fitted: with its shape
free, and with its shape fixed (one point on a known arc places it)."""
RADIUS_STARTS = np.array([0.2, 0.6, 1.8, 5.5])
ANGLE_STARTS = np.radians(np.array([25.0, 45.0, 65.0]))
START_STRIDE = 2
"""Starting points are tried on every second point: a start only needs the right basin."""
LIP_MM = 0.3
"""Points up to this far above a chamfer near its foot are a lip (a burr), part of it."""


@njit(cache=True, nogil=True)
def _truncated(r: float, sigma: float) -> float:
    z = r / sigma
    return min(z * z, TRUNCATION * TRUNCATION)


@njit(cache=True, nogil=True)
def sampling(u: np.ndarray, d: np.ndarray, sigma: float, spacing: float) -> tuple[float, float]:
    """(mean residual gap, largest gap) of the top's sampling along u, from the sorted u
    of its points between −``band_far_mm`` and −0.2 mm. The mean distance from the last
    sample to an edge that falls anywhere between samples is Σg² / 2Σg over the gaps g
    (the renewal residual): s/2 for a grid whose lines all share one phase, 1/density for
    lines at random phases — unlike "half the mean spacing" it is right for both."""
    far, near = band_far_mm(spacing), EXTENT_BAND_MM[1]
    band = np.empty(u.shape[0])
    n = 0
    for i in range(u.shape[0]):
        if abs(d[i]) < TRUNCATION * sigma and -far <= u[i] < -near:
            band[n] = u[i]
            n += 1
    if n < 8:
        return np.nan, np.nan
    band = np.sort(band[:n])
    gaps = band[1:] - band[:-1]
    total = gaps.sum()
    if total <= 0:
        return np.nan, np.nan
    return (gaps * gaps).sum() / (2.0 * total), gaps.max()


@njit(cache=True, nogil=True)
def sampling_gaps(
    starts: np.ndarray, u: np.ndarray, d: np.ndarray, sigma: np.ndarray, spacing: float
) -> np.ndarray:
    """(sides,) each side's largest gap of ``sampling`` (NaN where too few points)."""
    out = np.full(starts.shape[0] - 1, np.nan)
    for g in range(starts.shape[0] - 1):
        lo, hi = starts[g], starts[g + 1]
        out[g] = sampling(u[lo:hi], d[lo:hi], sigma[g], spacing)[1]
    return out


SHAPE_COLUMNS = 4
"""An arc or a chamfer places its edge more finely than its points are spaced only when
its points below the top stand at this many places across at least (``shape_columns``):
fewer (a coarse grid along the seam puts one or two columns on it) and a chamfer fits as
an arc, and an arc as another."""


@njit(cache=True, nogil=True)
def shape_columns(
    starts: np.ndarray, u: np.ndarray, d: np.ndarray, sigma: np.ndarray, spacing: float
) -> np.ndarray:
    """(sides,) at how many places across (a tenth of a spacing apart) each side's points
    lie below its top (more than 3σ), from 0.2 mm inside its end on: its pooled profiles'
    columns on an arc or a chamfer."""
    out = np.zeros(starts.shape[0] - 1, np.int64)
    width = 0.1 * spacing
    for g in range(starts.shape[0] - 1):
        lo, hi = starts[g], starts[g + 1]
        column = np.empty(hi - lo)
        n = 0
        for i in range(lo, hi):
            if d[i] > TRUNCATION * sigma[g] and u[i] > -EXTENT_BAND_MM[1]:
                column[n] = np.floor(u[i] / width)
                n += 1
        if n:
            out[g] = np.unique(column[:n]).shape[0]
    return out


@njit(cache=True, nogil=True)
def last_point(values: np.ndarray, start: float, largest_gap: float) -> float:
    """The last of the sorted ``values`` reached from ``start`` without a jump wider than
    three of the sampling's largest gaps (0.05 mm at least): a stray beyond is ignored."""
    reach = start
    limit = max(3.0 * largest_gap, 0.05)
    for value in np.sort(values):
        if value < reach:
            continue
        if value - reach > limit:
            break
        reach = value
    return reach


@njit(cache=True, nogil=True)
def top_end(
    u: np.ndarray, d: np.ndarray, sigma: float, spacing: float
) -> tuple[float, float, float]:
    """(last point, the sampling's mean residual gap, its largest gap) of a top that ends
    where its points stop (NaN where too few). Points above the top (a burr) count, and so
    do points less than 3σ + one point ``spacing`` below it: where a stitch merged the
    corner's last top point with a side-face point seen in the same voxel, their mean
    lies just below the top (a pixel mixed with the floor lies far deeper)."""
    residual, largest = sampling(u, d, sigma, spacing)
    if not np.isfinite(residual):
        return np.nan, np.nan, np.nan
    top = np.empty(u.shape[0])
    n = 0
    for i in range(u.shape[0]):
        if d[i] < TRUNCATION * sigma + spacing and u[i] >= -EXTENT_BAND_MM[1]:
            top[n] = u[i]
            n += 1
    return last_point(top[:n], -EXTENT_BAND_MM[1], largest), residual, largest


@njit(cache=True, nogil=True)
def extent(u: np.ndarray, d: np.ndarray, sigma: float, spacing: float) -> tuple[float, float]:
    """(X, σ_X) of a top that ends where its points stop (``top_end``): its last point plus
    the sampling's mean residual gap; σ_X = largest gap / √12."""
    last, residual, largest = top_end(u, d, sigma, spacing)
    return last + residual, largest / np.sqrt(12.0)


MIN_RETURN_DEG = 60.0
"""A sensor returns points from a surface inclined up to this much to its view at least
(the simulator's up to 75°; laser profilers 60–80°): an arc is seen from its start to at
least this slope."""


@njit(cache=True, nogil=True)
def arc_extent(
    u: np.ndarray, d: np.ndarray, sigma: float, spacing: float, radius: float
) -> tuple[float, float]:
    """(X, σ_X) of an arc of ``radius`` that no point of the section lies on (none below
    the top by 3σ): its start u_c is no further in than the top's last point less where
    the arc leaves the top by 3σ (√(6ρσ)), and no further out than where the next sample
    after that point — in the gap, or where the arc is too steep to return a point —
    lies, less the arc's part a sensor sees (ρ sin ``MIN_RETURN_DEG``). X = u_c + ρ, in the
    middle of that range, σ_X its width / √12 (NaN where the range is empty: a radius
    the points contradict). A round edge on a coarse grid along the seam: its arc may
    fall between two samples in every section — a corner's extent put its side face
    half a spacing in (ρ 1 mm at 0.75 mm spacing)."""
    last, _, largest = top_end(u, d, sigma, spacing)
    seen = np.sin(np.radians(MIN_RETURN_DEG))
    low = last - np.sqrt(2.0 * radius * TRUNCATION * sigma) + radius
    high = last + largest + radius * (1.0 - seen)
    if not low <= high:
        return np.nan, np.nan
    return (low + high) / 2, (high - low) / np.sqrt(12.0)


@njit(cache=True, nogil=True)
def bare_extent(last: float, largest: float, sigma: float) -> tuple[float, float]:
    """(X, σ_X) of a top whose last point at ``last`` has no point below the top beyond
    it, whatever its edge's shape: a square corner stands within the stretch after it
    (``largest``), and an arc may have fallen between two samples — any radius whose
    seen part below 3σ (``arc_extent``) is shorter than the stretch, its side face up to
    ρ(1 − sin ``MIN_RETURN_DEG``) further out; its least, 1.5σ in (ρ = 1.5σ)."""
    seen = np.sin(np.radians(MIN_RETURN_DEG))
    root = np.sqrt(2.0 * TRUNCATION * sigma)
    radius = ((root + np.sqrt(root * root + 4.0 * seen * largest)) / (2.0 * seen)) ** 2
    low = last - 0.5 * TRUNCATION * sigma
    high = last + largest + radius * (1.0 - seen)
    return (low + high) / 2, (high - low) / np.sqrt(12.0)


@njit(cache=True, nogil=True)
def _square_residual(u: float, d: float, x: float) -> float:
    """Distance to the boundary of the quadrant u ≤ X, δ ≥ 0 (the panel's body)."""
    if d <= 0.0:
        return -d if u <= x else np.hypot(u - x, d)
    if u >= x:
        return u - x
    return min(d, x - u)


@njit(cache=True, nogil=True)
def _square(
    u: np.ndarray, d: np.ndarray, sigma: float, spacing: float, max_depth: float
) -> tuple[float, float, float, float, bool]:
    """(X, σ_X, cost, mean truncated r²/σ², side face seen): X from the side face's
    points when at least five are seen tightly, else from the top's extent."""
    x, sigma_x = extent(u, d, sigma, spacing)
    if not np.isfinite(x):
        return np.nan, np.nan, np.nan, np.nan, False
    reach = max(sigma_x * np.sqrt(12.0), spacing)
    wall, seen = _side_face(u, d, x, TRUNCATION * sigma, max_depth, reach, _tall(sigma, spacing))
    if seen:
        x, sigma_x = wall
    cost = 0.0
    for i in range(u.shape[0]):
        cost += _truncated(_square_residual(u[i], d[i], x), sigma)
    return x, sigma_x, cost, cost / max(u.shape[0], 1), seen


@njit(cache=True, nogil=True)
def _damped_step(
    a: float, b: float, dd: float, g1: float, g2: float, both: bool
) -> tuple[float, float]:
    """One Levenberg-damped Gauss–Newton step from the normal equations [[a, b], [b, dd]]
    and the gradient (g1, g2); the first parameter alone when not ``both``."""
    if not both:
        return -g1 / a, 0.0
    damp = 1e-3 * (a + dd)
    det = (a + damp) * (dd + damp) - b * b
    return -((dd + damp) * g1 - b * g2) / det, -((a + damp) * g2 - b * g1) / det


@njit(cache=True, nogil=True)
def _round_residual(u: float, d: float, centre: float, radius: float) -> tuple[float, float, float]:
    """(r, ∂r/∂u_c, ∂r/∂ρ) to the top ray (u < u_c), the arc, or the side face (δ ≥ ρ)."""
    if d >= radius:
        return u - centre - radius, -1.0, -1.0
    if u < centre:
        if d < 0:
            return -d, 0.0, 0.0
        # The side face's distance, compared squared: its square root only where taken.
        to_face = (u - centre - radius, d - radius)
        if d * d <= to_face[0] ** 2 + to_face[1] ** 2:
            return d, 0.0, 0.0
        return np.hypot(to_face[0], to_face[1]), 0.0, 0.0
    du, dz = u - centre, d - radius
    distance = max(np.hypot(du, dz), 1e-9)
    return distance - radius, -du / distance, -dz / distance - 1.0


@njit(cache=True, nogil=True)
def implied_corner(model: int, u: np.ndarray, d: np.ndarray, sigma: float, shape: float) -> float:
    """Where the points below the top (by more than 3σ, at most a radius for an arc) place
    the chamfer's or the arc's start u_c, given its angle or radius ``shape``: the median
    over them of u − δ / tan α, or of u − √(2ρδ − δ²). A coarse profile has one or two
    such points, anywhere up to a spacing past the top's last point: a start at that point
    leaves each of them beyond the truncation, where the fit has no slope to follow.
    NaN where no point is below the top."""
    implied = np.empty(u.shape[0])
    n = 0
    for i in range(u.shape[0]):
        if d[i] <= TRUNCATION * sigma:
            continue
        if model == CHAMFER:
            implied[n] = u[i] - d[i] / np.tan(shape)
            n += 1
        elif d[i] <= shape:
            implied[n] = u[i] - np.sqrt(2.0 * shape * d[i] - d[i] * d[i])
            n += 1
    return np.median(implied[:n]) if n else np.nan


@njit(cache=True, nogil=True)
def _round(
    u: np.ndarray, d: np.ndarray, sigma: float, spacing: float, fixed_radius: float
) -> tuple[float, float, float, float, float, float]:
    """(u_c, ρ, X, σ_X, cost, mean truncated r²/σ²) of the arc model; ρ fixed when
    ``fixed_radius`` is finite. Started from several radii (the fit has local minima),
    then ``_gauss_newton``."""
    fit_radius = not np.isfinite(fixed_radius)
    below = 0
    for i in range(u.shape[0]):
        below += d[i] > TRUNCATION * sigma
    if below == 0 and not fit_radius:  # the arc between two samples: its extent
        x, sigma_x = arc_extent(u, d, sigma, spacing, fixed_radius)
        cost = _cost(ROUND, u, d, x - fixed_radius, fixed_radius, sigma)
        return x - fixed_radius, fixed_radius, x, sigma_x, cost, cost / u.shape[0]
    if below < MIN_EDGE_POINTS[0 if fit_radius else 1]:
        return np.nan, np.nan, np.nan, np.nan, np.nan, np.nan
    best_cost, centre, radius = np.inf, 0.0, 1.0
    starts = RADIUS_STARTS if fit_radius else np.array([fixed_radius])
    for start in starts:
        # Tangent where the top's points leave the top by about 3σ; and where the points
        # below the top place it on an arc of this radius.
        c0 = -np.sqrt(2.0 * start * TRUNCATION * sigma)
        tries = np.array([c0, 1.5 * c0, implied_corner(ROUND, u, d, sigma, start)])
        for c in tries if fit_radius else tries[::2]:
            if not np.isfinite(c):
                continue
            cost = _cost(ROUND, u[::START_STRIDE], d[::START_STRIDE], c, start, sigma)
            if cost < best_cost:
                best_cost, centre, radius = cost, c, start
    centre, radius, best_cost, a, b, dd = _gauss_newton(
        ROUND, u, d, sigma, centre, radius, best_cost, fit_radius
    )
    # X = u_c + ρ: its variance from the normal equations (ρ's own, when fixed, is the
    # seam's and is added by the caller).
    if fit_radius:
        det = a * dd - b * b
        variance = (dd - 2 * b + a) / det if det > 0 else np.inf
    else:
        variance = 1.0 / a
    sigma_x = sigma * np.sqrt(max(variance, 0.0))
    return centre, radius, centre + radius, sigma_x, best_cost, best_cost / u.shape[0]


@njit(cache=True, nogil=True)
def _chamfer_residual(
    u: float, d: float, corner: float, sin: float, cos: float
) -> tuple[float, float, float]:
    """(r, ∂r/∂u_c, ∂r/∂α) to the top ray (u < u_c) or the chamfer's ray from (u_c, 0) at
    the angle α whose sine and cosine are given (computed once per pass by the caller)."""
    along = (u - corner) * cos + d * sin
    across = (u - corner) * sin - d * cos
    # The top ray's distance is compared squared: its square root only where it is taken.
    if u <= corner:
        to_top = abs(d)
        if along < 0 or to_top < abs(across):
            return to_top, 0.0, 0.0
    elif along < 0 or (u - corner) ** 2 + d * d < across * across:
        return np.hypot(u - corner, d), 0.0, 0.0
    return across, -sin, (u - corner) * cos + d * sin


@njit(cache=True, nogil=True)
def _residual(
    model: int, u: float, d: float, p1: float, p2: float, trig: tuple[float, float]
) -> tuple[float, float, float]:
    """(r, ∂r/∂p1, ∂r/∂p2) of the arc (p1 = u_c, p2 = ρ) or the chamfer (u_c, α), with
    ``trig`` = (sin p2, cos p2)."""
    if model == ROUND:
        return _round_residual(u, d, p1, p2)
    return _chamfer_residual(u, d, p1, trig[0], trig[1])


@njit(cache=True, nogil=True)
def _cost(model: int, u: np.ndarray, d: np.ndarray, p1: float, p2: float, sigma: float) -> float:
    cost = 0.0
    trig = (np.sin(p2), np.cos(p2))
    for i in range(u.shape[0]):
        cost += _truncated(_residual(model, u[i], d[i], p1, p2, trig)[0], sigma)
    return cost


@njit(cache=True, nogil=True)
def _gauss_newton(
    model: int,
    u: np.ndarray,
    d: np.ndarray,
    sigma: float,
    p1: float,
    p2: float,
    cost: float,
    fit_second: bool,
) -> tuple[float, float, float, float, float, float]:
    """Damped Gauss–Newton on the inliers (|r| < 3σ) from (p1, p2) of cost ``cost``, the
    shape p2 only if ``fit_second``; steps bounded (u_c by 0.5 mm for an arc, 0.3 for a
    chamfer; ρ by half itself within 0.1–10 mm, α by 0.2 rad within 10–80°), stopping
    when the cost rises (the step is undone) or nothing moves by 0.1 µm. One pass over the
    points per step: it gives the cost where the last step landed and the next step's
    normal equations. Returns (p1, p2, cost, and the normal equations a, b, dd there)."""
    limit = TRUNCATION * sigma
    back1, back2, back = p1, p2, (1.0, 0.0, 1.0)
    a = b = dd = 1.0
    for iteration in range(16):
        a, b, dd, g1, g2, here = 1e-9, 0.0, 1e-9, 0.0, 0.0, 0.0
        trig = (np.sin(p2), np.cos(p2))
        for i in range(u.shape[0]):
            r, j1, j2 = _residual(model, u[i], d[i], p1, p2, trig)
            here += _truncated(r, sigma)
            if abs(r) < limit:
                a += j1 * j1
                b += j1 * j2
                dd += j2 * j2
                g1 += j1 * r
                g2 += j2 * r
        if iteration and here > cost:  # the last step made it worse: undo it
            return back1, back2, cost, back[0], back[1], back[2]
        cost, back1, back2, back = here, p1, p2, (a, b, dd)
        step1, step2 = _damped_step(a, b, dd, g1, g2, fit_second)
        if model == ROUND:
            new1 = p1 + min(max(step1, -0.5), 0.5)
            new2 = p2 + min(max(step2, -0.5 * p2), 0.5 * p2)
            new2 = min(max(new2, MIN_RADIUS_MM), MAX_RADIUS_MM)
        else:
            new1 = p1 + min(max(step1, -0.3), 0.3)
            new2 = min(max(p2 + min(max(step2, -0.2), 0.2), MIN_ANGLE), MAX_ANGLE)
        if abs(new1 - p1) + abs(new2 - p2) < 1e-4:
            break
        p1, p2 = new1, new2
    return back1, back2, cost, back[0], back[1], back[2]


@njit(cache=True, nogil=True)
def _chamfer(
    u: np.ndarray,
    d: np.ndarray,
    sigma: float,
    spacing: float,
    fixed_angle: float,
    max_depth: float,
) -> tuple[float, float, float, float, float, float, bool]:
    """(u_c, α, X, σ_X, cost, mean truncated r²/σ², side face seen) of the chamfer model;
    α fixed when ``fixed_angle`` is finite; X from the extent of the chamfer's points or
    the side face below its foot."""
    limit = TRUNCATION * sigma
    fit_angle = not np.isfinite(fixed_angle)
    count = 0
    for i in range(u.shape[0]):
        count += limit < d[i] < max_depth
    if count < MIN_EDGE_POINTS[0 if fit_angle else 1]:
        return np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, False
    best_cost, corner, angle = np.inf, 0.0, np.radians(45.0)
    starts = ANGLE_STARTS if fit_angle else np.array([fixed_angle])
    for start in starts:
        tries = np.array([0.0, -0.1, implied_corner(CHAMFER, u, d, sigma, start)])
        for c0 in tries if fit_angle else tries[::2]:
            if not np.isfinite(c0):
                continue
            cost = _cost(CHAMFER, u[::START_STRIDE], d[::START_STRIDE], c0, start, sigma)
            if cost < best_cost:
                best_cost, corner, angle = cost, c0, start
    corner, angle, best_cost, _, _, _ = _gauss_newton(
        CHAMFER, u, d, sigma, corner, angle, best_cost, fit_angle
    )
    # The foot: the chamfer's last point (in u, sampled like the top) plus the residual
    # gap — or the side face below it, where a view sees it.
    residual, largest = sampling(u, d, sigma, spacing)
    if not np.isfinite(residual):
        return np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, False
    on_face = np.empty(u.shape[0])
    n = 0
    sin, cos = np.sin(angle), np.cos(angle)
    for i in range(u.shape[0]):
        r, _, _ = _chamfer_residual(u[i], d[i], corner, sin, cos)
        # On the face, above it (a lip), or just below it (merged with the side face).
        if -(limit + spacing) < r < LIP_MM and d[i] > limit:
            on_face[n] = u[i]
            n += 1
    if n < MIN_EDGE_POINTS[1]:
        return np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, False
    # Face points start where the chamfer is 3σ below the top.
    x = last_point(on_face[:n], corner + limit / np.tan(angle), largest) + residual
    sigma_x = largest / np.sqrt(12.0)
    foot = (x - corner) * np.tan(angle)
    wall, seen = _side_face(
        u, d, x, foot + limit, max_depth, max(largest, spacing), _tall(sigma, spacing)
    )
    if seen:
        x, sigma_x = wall
    cost = 0.0
    foot = (x - corner) * np.tan(angle)  # at X as placed
    length = np.hypot(x - corner, foot)
    for i in range(u.shape[0]):
        cost += _truncated(_chamfer_polyline(u[i], d[i], corner, x, foot, length), sigma)
    return corner, angle, x, sigma_x, cost, cost / u.shape[0], seen


@njit(cache=True, nogil=True)
def _chamfer_polyline(
    u: float, d: float, corner: float, x: float, foot: float, length: float
) -> float:
    """Distance to the whole chamfered edge: the top up to u_c, the face down to its foot
    at u = X, depth ``foot`` ((X − u_c)·tan α), and the side face below; ``length`` is
    the face's, from (u_c, 0) to (X, foot)."""
    t = ((u - corner) * (x - corner) + d * foot) / max(length * length, 1e-12)
    t = min(max(t, 0.0), 1.0)
    # The offsets to the nearest point of each part (hypot(0, δ) = |δ| exactly), compared
    # squared: one square root, of the nearest.
    top = (0.0 if u <= corner else u - corner, d)
    face = (u - corner - t * (x - corner), d - t * foot)
    wall = (u - x, 0.0 if d >= foot else d - foot)
    nearest = top
    for part in (face, wall):
        if part[0] ** 2 + part[1] ** 2 < nearest[0] ** 2 + nearest[1] ** 2:
            nearest = part
    return np.hypot(nearest[0], nearest[1])


@njit(cache=True, nogil=True)
def _tall(sigma: float, spacing: float) -> float:
    """The least height a side face's points span to count as one: more than the noise
    spreads points of one depth (2 × 3σ) and than one point spacing."""
    return max(2.0 * TRUNCATION * sigma, spacing)


@njit(cache=True, nogil=True)
def _side_face(
    u: np.ndarray,
    d: np.ndarray,
    x: float,
    below: float,
    max_depth: float,
    reach: float,
    tall: float,
) -> tuple[tuple[float, float], bool]:
    """((X, σ_X), seen) from the points of a side face standing near u = ``x`` deeper than
    ``below``: their median u, when at least five lie within a third of ``reach`` of it
    and they stand at least ``tall`` high. A wall is seen down its height; points at one u
    and one depth are a sloped face sampled by one column of a grid turned along the
    seam, not a wall."""
    wall = np.empty(u.shape[0])
    depth = np.empty(u.shape[0])
    n = 0
    for i in range(u.shape[0]):
        if below < d[i] < max_depth and abs(u[i] - x) < 1.5 * reach:
            wall[n] = u[i]
            depth[n] = d[i]
            n += 1
    if n < 5 or depth[:n].max() - depth[:n].min() < tall:
        return (x, np.nan), False
    face = np.sort(wall[:n])
    median = face[n // 2]
    spread = 1.4826 * np.median(np.abs(face - median))
    if spread >= reach / 3:
        return (x, np.nan), False
    return (median, max(1.25 * spread / np.sqrt(n), 0.002)), True


@njit(cache=True, nogil=True)
def _free(
    u: np.ndarray, d: np.ndarray, sigma: float, spacing: float, max_depth: float
) -> tuple[float, float, float]:
    """(X, σ_X, unexplained width): the top's extent; σ_X covers the contiguous run of
    points below the top beyond it, which no model explains — or, where there is none,
    any shape of edge the points allow (``bare_extent``)."""
    last, residual, largest = top_end(u, d, sigma, spacing)
    if not np.isfinite(last):
        return np.nan, np.nan, np.nan
    x = last + residual
    beyond = np.empty(u.shape[0])
    n = 0
    for i in range(u.shape[0]):
        if u[i] > x and TRUNCATION * sigma < d[i] < max_depth:
            beyond[n] = u[i]
            n += 1
    width, reach = 0.0, x
    for value in np.sort(beyond[:n]):
        if value - reach > max(2.0 * largest, spacing):
            break
        reach = value
    width = reach - x
    if n == 0:
        x, sigma_x = bare_extent(last, largest, sigma)
        return x, sigma_x, 0.0
    return x, np.sqrt((largest**2 + width**2) / 12.0), width


@njit(cache=True, nogil=True)
def burr_height(u: np.ndarray, d: np.ndarray, sigma: float) -> float:
    """How far points stand above the top in its last 0.5 mm (a lip at the edge): the
    third highest, so a spike alone is not a burr; 0 with fewer than three."""
    heights = np.empty(u.shape[0])
    n = 0
    for i in range(u.shape[0]):
        if u[i] > -0.5 and d[i] < -TRUNCATION * sigma:
            heights[n] = -d[i]
            n += 1
    return np.sort(heights[:n])[-3] if n >= 3 else 0.0


FIELDS = 6
"""Per side and model: u_c, shape (ρ or α), X, σ_X, cost, mean truncated r²/σ²."""


@njit(cache=True, nogil=True)
def fit_sides(
    starts: np.ndarray,
    u: np.ndarray,
    d: np.ndarray,
    sigma: np.ndarray,
    spacing: float,
    max_depth: float,
    models: np.ndarray,
    fixed_shape: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Fit to every side g (points starts[g]:starts[g+1]) the models ``models[g]`` asks
    for ((sides, 4) bool: a side's own model only, once it is chosen; none: the side is
    skipped), with noise ``sigma[g]``; ``fixed_shape[g]`` fixes ρ or α where finite.
    Returns ((sides, 4, FIELDS) fits, NaN where not fitted; (sides, 4) burr height,
    unexplained width of the free model, 1 where the square model, and where the chamfer
    model, placed X on a side face it saw)."""
    sides = starts.shape[0] - 1
    out = np.full((sides, 4, FIELDS), np.nan)
    extra = np.zeros((sides, 4))
    for g in range(sides):
        lo, hi = starts[g], starts[g + 1]
        if hi - lo < 10 or not models[g].any():
            continue
        ug, dg, s = u[lo:hi], d[lo:hi], sigma[g]
        if models[g, SQUARE]:
            x, sx, cost, q, seen = _square(ug, dg, s, spacing, max_depth)
            out[g, SQUARE, 2:] = x, sx, cost, q
            extra[g, 2] = seen
        if models[g, CHAMFER]:
            c, a, x, sx, cost, q, seen = _chamfer(ug, dg, s, spacing, fixed_shape[g], max_depth)
            out[g, CHAMFER] = c, a, x, sx, cost, q
            extra[g, 3] = seen
        if models[g, ROUND]:
            out[g, ROUND] = _round(ug, dg, s, spacing, fixed_shape[g])
        if models[g, FREE]:
            x, sx, width = _free(ug, dg, s, spacing, max_depth)
            out[g, FREE, 2], out[g, FREE, 3] = x, sx
            extra[g, 1] = width
        extra[g, 0] = burr_height(ug, dg, s)
    return out, extra
