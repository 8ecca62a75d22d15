"""The direct alignment's inner loops, compiled and without the interpreter's lock.

One Gauss–Newton level was some twenty NumPy calls per iteration on a few thousand
points (a sampling, a brightness fit, weights, the normal equations): each call is short,
and between them the thread holds the interpreter, so two threads aligned only 1.5× as
fast as one. Here a level's whole loop, and the sharpness's match cost, are one call each
(numba, ``nogil``): the arithmetic is the same as ``direct``'s NumPy version was (bilinear
sampling in float64, as SciPy's ``map_coordinates`` with ``order=1``), its sums in float64.
"""

from __future__ import annotations

import numpy as np
from numba import njit

HUBER = 1.345
MIN_OVERLAP_TO_STEP = 0.2
"""Below this share of the template's points inside the image a level stops stepping."""


@njit(cache=True, nogil=True)
def _sample(
    image: np.ndarray, xy: np.ndarray, motion: np.ndarray, values: np.ndarray, inside: np.ndarray
) -> None:
    """``image`` at R(θ)·xy + t about its centre, bilinear in float64, into ``values``;
    ``inside``: the position lies within the image (outside: the edge pixel's value).
    Not OpenCV's remap, which rounds positions to 1/32 pixel: on a real photograph that
    rounding alone doubled the heading's frame-to-frame noise and left a bias of 0.0003° a
    frame (measured on a KITTI frame with texels finer than the pixels)."""
    rows, cols = image.shape
    cx, cy = (cols - 1) / 2.0, (rows - 1) / 2.0
    c, s = np.cos(motion[2]), np.sin(motion[2])
    for k in range(xy.shape[0]):
        x = c * xy[k, 0] - s * xy[k, 1] + (motion[0] + cx)
        y = s * xy[k, 0] + c * xy[k, 1] + (motion[1] + cy)
        inside[k] = x >= 0.0 and x <= cols - 1 and y >= 0.0 and y <= rows - 1
        x = min(max(x, 0.0), cols - 1.0)
        y = min(max(y, 0.0), rows - 1.0)
        x0, y0 = min(int(x), cols - 2), min(int(y), rows - 2)
        fx, fy = x - x0, y - y0
        top = (1.0 - fx) * image[y0, x0] + fx * image[y0, x0 + 1]
        bottom = (1.0 - fx) * image[y0 + 1, x0] + fx * image[y0 + 1, x0 + 1]
        values[k] = (1.0 - fy) * top + fy * bottom


@njit(cache=True, nogil=True)
def _means(
    sampled: np.ndarray, value: np.ndarray, inside: np.ndarray, seen: int
) -> tuple[float, float]:
    """The means of the ``seen`` sampled and template values inside the image."""
    seen_mean, wanted_mean = 0.0, 0.0
    for k in range(sampled.shape[0]):
        if inside[k]:
            seen_mean += sampled[k]
            wanted_mean += value[k]
    return seen_mean / seen, wanted_mean / seen


@njit(cache=True, nogil=True)
def _compose_inverse(motion: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """motion ∘ delta⁻¹ for warps p ↦ R p + t (the inverse-compositional update)."""
    c, s = np.cos(delta[2]), np.sin(delta[2])
    ix, iy = -(c * delta[0] + s * delta[1]), s * delta[0] - c * delta[1]
    cm, sm = np.cos(motion[2]), np.sin(motion[2])
    out = np.empty(3)
    out[0] = motion[0] + cm * ix - sm * iy
    out[1] = motion[1] + sm * ix + cm * iy
    out[2] = motion[2] - delta[2]
    return out


@njit(cache=True, nogil=True)
def align_level(
    image: np.ndarray,
    xy: np.ndarray,
    value: np.ndarray,
    jac: np.ndarray,
    start: np.ndarray,
    iterations: int,
    converged_px: float,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Gauss–Newton from ``start`` (level pixels) on one level: the warp from the template's
    points ``xy`` (values ``value``, Jacobians ``jac``) to ``image``, J^T W J, the robust
    residual's RMS and the overlap.

    Each step refits the brightness (value ≈ gain · sampled + offset over the overlap) and
    weighs the errors by Huber's rule at 1.345 σ (σ from the mean absolute error)."""
    n = xy.shape[0]
    sampled = np.empty(n)
    inside = np.empty(n, np.bool_)
    error = np.zeros(n)
    motion = start.copy()
    hessian = np.eye(3)
    residual, overlap = np.inf, 0.0
    extent = np.abs(xy).max()
    for _ in range(iterations):
        _sample(image, xy, motion, sampled, inside)
        seen = inside.sum()
        overlap = seen / n
        if overlap < MIN_OVERLAP_TO_STEP:
            break
        seen_mean, wanted_mean = _means(sampled, value, inside, seen)
        spread, covariance = 0.0, 0.0
        for k in range(n):
            if inside[k]:
                spread += (sampled[k] - seen_mean) ** 2
                covariance += (sampled[k] - seen_mean) * (value[k] - wanted_mean)
        gain = covariance / spread if spread > 0 else 1.0
        offset = wanted_mean - gain * seen_mean
        absolute = 0.0
        for k in range(n):
            error[k] = gain * sampled[k] + offset - value[k] if inside[k] else 0.0
            absolute += abs(error[k])
        scale = 1.2533 * absolute / seen + 1e-6  # σ of Gaussian errors
        # The normal equations summed in scalars (registers), not in arrays the compiler
        # must store to at every point.
        h00 = h01 = h02 = h11 = h12 = h22 = g0 = g1 = g2 = squares = weights = 0.0
        for k in range(n):
            w = min(1.0, HUBER * scale / (abs(error[k]) + 1e-12)) if inside[k] else 0.0
            j0, j1, j2 = jac[k, 0], jac[k, 1], jac[k, 2]
            w0, w1, w2 = w * j0, w * j1, w * j2
            g0, g1, g2 = g0 + w0 * error[k], g1 + w1 * error[k], g2 + w2 * error[k]
            h00, h01, h02 = h00 + w0 * j0, h01 + w0 * j1, h02 + w0 * j2
            h11, h12, h22 = h11 + w1 * j1, h12 + w1 * j2, h22 + w2 * j2
            squares += w * error[k] ** 2
            weights += w
        hessian = np.array([[h00, h01, h02], [h01, h11, h12], [h02, h12, h22]])
        gradient = np.array([g0, g1, g2])
        delta = np.linalg.solve(hessian + 1e-9 * np.eye(3), gradient)
        motion = _compose_inverse(motion, delta)
        residual = np.sqrt(squares / max(weights, 1.0))
        if np.hypot(delta[0], delta[1]) + abs(delta[2]) * extent < converged_px:
            break
    return motion, hessian, residual, overlap


@njit(cache=True, nogil=True)
def match_cost(image: np.ndarray, xy: np.ndarray, value: np.ndarray, motion: np.ndarray) -> float:
    """How badly ``image`` at the warped ``xy`` matches ``value``: the mean squared
    difference over the overlap after matching means and spreads."""
    n = xy.shape[0]
    sampled = np.empty(n)
    inside = np.empty(n, np.bool_)
    _sample(image, xy, motion, sampled, inside)
    seen = max(inside.sum(), 1)
    seen_mean, wanted_mean = _means(sampled, value, inside, seen)
    seen_var, wanted_var = 0.0, 0.0
    for k in range(n):
        if inside[k]:
            seen_var += (sampled[k] - seen_mean) ** 2
            wanted_var += (value[k] - wanted_mean) ** 2
    gain = np.sqrt(wanted_var / seen) / (np.sqrt(seen_var / seen) + 1e-9)
    total = 0.0
    for k in range(n):
        if inside[k]:
            total += (gain * (sampled[k] - seen_mean) - (value[k] - wanted_mean)) ** 2
    return total / seen


@njit(cache=True, nogil=True)
def sharpness(image: np.ndarray, xy: np.ndarray, value: np.ndarray, motion: np.ndarray) -> float:
    """How much worse ``image`` matches one pixel off ``motion`` (along x and y, the
    smaller) than at it, relative: ``match_cost`` at the motion and at the four shifts,
    one call."""
    base = match_cost(image, xy, value, motion)
    worse = np.empty(4)
    for m in range(4):
        shifted = motion.copy()
        shifted[m // 2] += 1.0 if m % 2 == 0 else -1.0
        worse[m] = match_cost(image, xy, value, shifted)
    return min(min(worse[0], worse[1]), min(worse[2], worse[3])) / (base + 1e-9) - 1.0


@njit(cache=True, nogil=True)
def _select(values: np.ndarray, k: int) -> np.float32:
    """The value ``np.partition(values, k)[k]`` would give (the k-th smallest) of
    contiguous, non-negative float32 ``values`` (gradient energies): their bits, read as
    unsigned integers, keep their order, so the k-th is found 11, 11 and 10 bits at a time,
    a counting pass each. A sixth of quickselect's time on a frame's 9 600 samples (0.070
    → 0.012 ms: quickselect's comparisons branch unpredictably)."""
    bits = values.view(np.uint32)
    counts = np.empty(2048, np.int64)
    prefix, high = 0, 32  # the bits found so far: those above ``high``
    for width in (11, 11, 10):
        shift = high - width
        counts[:] = 0
        for m in range(bits.size):
            v = np.int64(bits[m])
            if v >> high == prefix >> high:
                counts[(v >> shift) & ((1 << width) - 1)] += 1
        bucket = 0
        while k >= counts[bucket]:
            k -= counts[bucket]
            bucket += 1
        prefix |= bucket << shift
        high = shift
    found = np.empty(1, np.uint32)
    found[0] = prefix
    return found.view(np.float32)[0]


@njit(cache=True, nogil=True, inline="always")
def _gradient(level: np.ndarray, r: int, c: int) -> tuple[np.float32, np.float32]:
    """(d/dx, d/dy) of ``level`` at pixel (r, c): the 3 × 3 Sobel kernels over 8 (OpenCV's
    ``Sobel(ksize=3, scale=1 / 8)`` but for the order of the float additions)."""
    two, eighth = np.float32(2), np.float32(0.125)  # float32 throughout, as OpenCV's
    up, down, left, right = r - 1, r + 1, c - 1, c + 1  # indexed, not row views: no refcounts
    gx = (level[up, right] - level[up, left]) + two * (level[r, right] - level[r, left])
    gy = (level[down, left] - level[up, left]) + two * (level[down, c] - level[up, c])
    gx += level[down, right] - level[down, left]
    gy += level[down, right] - level[up, right]
    return gx * eighth, gy * eighth


@njit(cache=True, nogil=True)
def _energy_row(up: np.ndarray, mid: np.ndarray, down: np.ndarray, out: np.ndarray) -> None:
    """gx² + gy² (``_gradient``'s, the same float32 operations in the same order) at pixels
    1 … len(out) of the row ``mid`` between rows ``up`` and ``down``, into ``out``. Rows
    passed as arrays of their own, indexed from 0: the compiler then turns the loop into
    SIMD (16 pixels an instruction with AVX-512), which it does not for the same arithmetic
    on a 2-D image's rows and columns (one pixel at a time, about 3× the time)."""
    two, eighth = np.float32(2), np.float32(0.125)
    for j in range(out.size):
        gx = (up[j + 2] - up[j]) + two * (mid[j + 2] - mid[j])
        gy = (down[j] - up[j]) + two * (down[j + 1] - up[j + 1])
        gx += down[j + 2] - down[j]
        gy += down[j + 2] - up[j + 2]
        gx, gy = gx * eighth, gy * eighth
        out[j] = gx * gx + gy * gy


@njit(cache=True, nogil=True)
def textured_points(
    level: np.ndarray, border: int, stride: int, count: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """About the ``count`` most textured pixels of float32 ``level`` among every
    ``stride``-th one ``border`` (≥ 1) pixels in from its edges: (N, 2) x, y about the
    level's centre, their grey levels and (N, 3) Jacobians d(value)/d(tx, ty, θ) at the
    identity, in row-major order.

    The most textured are those whose gradient energy gx² + gy² reaches the value every 8th
    candidate puts at the ``count``-th place (a fifth of a full partition's time). The
    energy is taken a candidates' row at a time (``_energy_row``; with a stride, at every
    pixel of the row and every ``stride``-th kept: at full size half the pixels, as SIMD,
    cost less than the quarter that compete one at a time), then the chosen points' gradients
    again: a pass over the rows instead of two whole-image Sobel filters and the dozen
    array operations (each a pass and a copy) it was in NumPy."""
    rows, cols = level.shape
    grid_rows = (rows - 2 * border + stride - 1) // stride
    grid_cols = (cols - 2 * border + stride - 1) // stride
    energy = np.empty(grid_rows * grid_cols, np.float32)
    span = max(stride * (grid_cols - 1) + 1, 0)  # the row's pixels, first candidate to last
    row_energy = np.empty(span, np.float32)
    left, right = border - 1, border + span + 1
    for i in range(grid_rows):
        r = border + i * stride
        up, mid, down = level[r - 1, left:right], level[r, left:right], level[r + 1, left:right]
        out = energy[i * grid_cols : (i + 1) * grid_cols]
        if stride == 1:
            _energy_row(up, mid, down, out)
        else:
            _energy_row(up, mid, down, row_energy)
            for j in range(grid_cols):
                out[j] = row_energy[j * stride]
    sample = energy[::8].copy()
    threshold = _select(sample, sample.size - max(1, count // 8))
    chosen = 0
    for m in range(energy.size):
        chosen += energy[m] >= threshold
    xy = np.empty((chosen, 2), np.float32)
    values = np.empty(chosen, np.float32)
    jacobians = np.empty((chosen, 3), np.float32)
    cx, cy = np.float32((cols - 1) / 2), np.float32((rows - 1) / 2)
    k = 0
    for i in range(grid_rows):
        r = border + i * stride
        for j in range(grid_cols):
            if energy[i * grid_cols + j] < threshold:
                continue
            c = border + j * stride
            x, y = np.float32(c) - cx, np.float32(r) - cy
            gx, gy = _gradient(level, r, c)
            xy[k, 0], xy[k, 1] = x, y
            values[k] = level[r, c]
            jacobians[k, 0], jacobians[k, 1] = gx, gy
            jacobians[k, 2] = -y * gx + x * gy
            k += 1
    return xy, values, jacobians
