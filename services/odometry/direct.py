"""vista's method: direct planar alignment of consecutive frames at full resolution.

The motion of frame j against frame i is the rigid planar warp that makes frame j,
sampled at the warped positions of frame i's textured pixels, look like frame i —
inverse-compositional Gauss–Newton on a three-level pyramid (the template's gradients and
Hessian are computed once per frame), with the brightness's gain and offset refitted at
each step (lights change, shadows move) and a Huber weight (what one frame shows and the
other does not). It starts from the previous pair's motion (a robot's speed changes little
in 1/60 s) and, when that does not converge, from phase correlation on a quarter-size
frame.

Each pair gets a covariance (residual variance × the Hessian's inverse), a sharpness (how
much worse the frames match one pixel off) and, when it failed, a reason: too little
overlap (too fast), frames that do not match after alignment (a floor that changed). Too
little texture (no sharpness) is a warning, not a failure: on a faint floor, under blur or
noise the alignment still lands within a few hundredths of a millimetre (measured on the
bench's floors) — far better than any guess — so the motion is kept with a larger σ.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from services.odometry.phase import pair_motion

LEVELS = 3
POINTS_PER_LEVEL = (6_000, 4_000, 3_000)
"""Template pixels used at full, half and quarter size (the most textured ones)."""
ITERATIONS = (6, 8, 10)
CONVERGED_PX = (0.005, 0.02, 0.05)
"""A level is done when a step moves its points less than this (level pixels)."""
HUBER = 1.345
MIN_SHARPNESS = 0.1
"""Below this the frames match barely worse one pixel off the found motion (noise matches
noise anywhere: a plain floor has little to align on) — the warning ``LOW_TEXTURE``."""
LOW_TEXTURE = "too little texture"
SHARPNESS_STRIDE = 3
"""The sharpness is measured on every third template pixel (4 000 of them)."""
MAX_RESIDUAL = 12.0
MAX_RESIDUAL_SHARE = 0.5
"""The frames do not match when the grey levels left after alignment (RMS) pass both
``MAX_RESIDUAL`` and this share of the template pixels' own spread: a floor of strong
contrast leaves more after a right alignment (interpolation, blur) than a plain one."""
MIN_OVERLAP = 0.5
FLAT_RANGE = (0.5, 1.5)
"""How far a lens's vignetting may take the light from its mean."""


@dataclass
class Template:
    """One frame prepared as the template of its pair (per pyramid level)."""

    images: list[np.ndarray]
    points: list[np.ndarray]
    """(N, 2) x, y of the chosen pixels about the level's centre."""
    values: list[np.ndarray]
    jacobians: list[np.ndarray]
    """(N, 3): d(value)/d(tx, ty, θ) at the identity."""


@dataclass(frozen=True)
class Alignment:
    motion_px: np.ndarray
    """tx, ty (full-size pixels), θ (rad): frame j's pixel q shows frame i's R q + t."""
    covariance: np.ndarray
    """(3, 3) of the motion (px², px·rad, rad²)."""
    residual: float
    overlap: float
    sharpness: float
    reason: str | None
    """Why the alignment failed (None: it did not)."""
    warning: str | None = None
    """Why its motion is less sure than its covariance says (too little texture)."""


def _centre(shape: tuple[int, int]) -> np.ndarray:
    return np.array([(shape[1] - 1) / 2, (shape[0] - 1) / 2])


def flat_field(frames: list[np.ndarray]) -> np.ndarray:
    """The lens's fixed fall-off of light over the frame (vignetting), mean 1: a radial
    surface a + b·r² + c·r⁴ about the centre fitted to the mean of ``frames``, whose
    texture averages out as the floor moves, and kept within ``FLAT_RANGE``. The pattern
    stays while the floor moves under it: left in, it pulls the heading a little at every
    frame. Radial only: a freer surface took up the scene itself when the floor had moved
    little or was a picture of strong contrast (a street photo's bright sky and dark road),
    and dividing it out printed that scene on every frame."""
    mean = np.mean([f.astype(np.float32) for f in frames], axis=0)
    rows, cols = mean.shape

    def terms(y: np.ndarray, x: np.ndarray) -> list[np.ndarray]:
        r2 = ((x - (cols - 1) / 2) ** 2 + (y - (rows - 1) / 2) ** 2) / cols**2
        return [np.ones_like(r2), r2, r2 * r2]

    y, x = np.mgrid[0:rows:4, 0:cols:4].astype(np.float64)
    design = np.column_stack([t.ravel() for t in terms(y, x)])
    coefficients = np.linalg.lstsq(design, mean[::4, ::4].ravel(), rcond=None)[0]
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    surface = sum(c * t for c, t in zip(coefficients, terms(y, x), strict=True))
    surface = surface / surface.mean()
    return np.clip(surface, *FLAT_RANGE).astype(np.float32)


def _strongest(values: np.ndarray, count: int) -> np.ndarray:
    """Flat indices of about the ``count`` largest ``values``: those at or above the
    threshold that every 8th value puts there (a fifth of ``argpartition``'s time)."""
    values = values.ravel()
    sample = values[::8]
    rank = sample.size - max(1, count // 8)
    return np.flatnonzero(values >= np.partition(sample, rank)[rank])


def prepare(image: np.ndarray, flat: np.ndarray | None = None) -> Template:
    """A frame's pyramid (divided by the light's ``flat`` field, if given), its most
    textured pixels per level and their Jacobians."""
    level = image.astype(np.float32)
    if flat is not None:
        level = level / flat
    images, points, values, jacobians = [], [], [], []
    for k in range(LEVELS):
        if k:
            level = cv2.pyrDown(level)
        gx = cv2.Sobel(level, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
        gy = cv2.Sobel(level, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
        border, stride = 4, 2 if k == 0 else 1  # at full size every other pixel competes
        inner = (slice(border, -border, stride), slice(border, -border, stride))
        magnitude = np.square(gx[inner]) + np.square(gy[inner])
        chosen = _strongest(magnitude, min(POINTS_PER_LEVEL[k], magnitude.size // 4))
        rows, cols = np.unravel_index(chosen, magnitude.shape)
        rows, cols = rows * stride + border, cols * stride + border
        centre = _centre(level.shape)
        xy = np.column_stack([cols - centre[0], rows - centre[1]]).astype(np.float32)
        gxs, gys = gx[rows, cols], gy[rows, cols]
        jacobians.append(np.column_stack([gxs, gys, -xy[:, 1] * gxs + xy[:, 0] * gys]))
        points.append(xy)
        values.append(level[rows, cols])
        images.append(level)
    return Template(images, points, values, jacobians)


def _sample(image: np.ndarray, xy: np.ndarray, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``image`` at R(θ)·xy + t (about its centre), bilinear in floating point, and which
    samples fell inside. OpenCV's remap rounds positions to 1/32 pixel: on a real
    photograph that rounding alone doubled the heading's frame-to-frame noise and left a
    bias of 0.0003° a frame (measured on a KITTI frame with texels finer than the pixels)."""
    from scipy.ndimage import map_coordinates

    c, s = np.cos(motion[2]), np.sin(motion[2])
    centre = _centre(image.shape)
    x = c * xy[:, 0] - s * xy[:, 1] + (motion[0] + centre[0])
    y = s * xy[:, 0] + c * xy[:, 1] + (motion[1] + centre[1])
    inside = (x >= 0) & (x <= image.shape[1] - 1) & (y >= 0) & (y <= image.shape[0] - 1)
    values = map_coordinates(image, (y, x), order=1, mode="nearest", prefilter=False)
    return values.astype(np.float32, copy=False), inside


def _compose_inverse(motion: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """motion ∘ delta⁻¹ for warps p ↦ R p + t (the inverse-compositional update)."""
    c, s = np.cos(delta[2]), np.sin(delta[2])
    inv_t = -np.array([c * delta[0] + s * delta[1], -s * delta[0] + c * delta[1]])
    cm, sm = np.cos(motion[2]), np.sin(motion[2])
    t = motion[:2] + np.array([cm * inv_t[0] - sm * inv_t[1], sm * inv_t[0] + cm * inv_t[1]])
    return np.array([t[0], t[1], motion[2] - delta[2]])


def _align_level(
    template: Template, level: int, image: np.ndarray, start: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Gauss–Newton at one level from ``start`` (level pixels): the warp from template to
    ``image`` coordinates, J^T W J, the robust residual RMS and the overlap."""
    xy, value, jac = template.points[level], template.values[level], template.jacobians[level]
    motion = start.copy()
    hessian = np.eye(3)
    residual, overlap = np.inf, 0.0
    for _ in range(ITERATIONS[level]):
        sampled, inside = _sample(image, xy, motion)
        overlap = float(inside.mean())
        if overlap < 0.2:
            break
        # brightness: fit value ≈ gain · sampled + offset over the overlap
        # (sums of products, not np.dot: OpenBLAS's 1-D dot took 1–2 ms on 12 000 values here)
        seen, wanted = sampled[inside], value[inside]
        seen_mean, wanted_mean = seen.mean(), wanted.mean()
        spread = ((seen - seen_mean) ** 2).sum()
        gain = ((seen - seen_mean) * (wanted - wanted_mean)).sum() / spread if spread > 0 else 1.0
        offset = wanted_mean - gain * seen_mean
        error = np.where(inside, gain * sampled + offset - value, 0.0).astype(np.float32)
        scale = 1.2533 * np.abs(error[inside]).mean() + 1e-6  # σ of Gaussian errors
        weight = np.where(inside, np.minimum(1.0, HUBER * scale / (np.abs(error) + 1e-12)), 0.0)
        weighted = jac * weight.astype(np.float32)[:, None]
        hessian = (jac.T @ weighted).astype(np.float64)
        gradient = (weighted.T @ error).astype(np.float64)
        delta = np.linalg.solve(hessian + 1e-9 * np.eye(3), gradient)
        motion = _compose_inverse(motion, delta)
        residual = float(np.sqrt(np.sum(weight * error**2) / max(np.sum(weight), 1.0)))
        extent = np.abs(xy).max()
        if np.hypot(delta[0], delta[1]) + abs(delta[2]) * extent < CONVERGED_PX[level]:
            break
    return motion, hessian, residual, overlap


def sharpness(template: Template, image: Template, warp: np.ndarray) -> float:
    """How much worse the frames match one pixel off the found warp (along x and y, the
    smaller): near 0 when the floor has nothing to align on (noise matches noise
    anywhere), or only lines along one direction."""
    xy, value = template.points[0][::SHARPNESS_STRIDE], template.values[0][::SHARPNESS_STRIDE]

    def cost(motion: np.ndarray) -> float:
        sampled, inside = _sample(image.images[0], xy, motion)
        seen, wanted = sampled[inside], value[inside]
        gain = np.std(wanted) / (np.std(seen) + 1e-9)
        error = gain * (seen - seen.mean()) - (wanted - wanted.mean())
        return float(np.mean(error**2))

    base = cost(warp)
    worse = [cost(warp + shift) for shift in ([1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0])]
    return float(min(min(worse[:2]), min(worse[2:])) / (base + 1e-9) - 1.0)


def _inverse(motion: np.ndarray) -> np.ndarray:
    """The inverse of the warp p ↦ R p + t."""
    c, s = np.cos(motion[2]), np.sin(motion[2])
    return np.array([-(c * motion[0] + s * motion[1]), s * motion[0] - c * motion[1], -motion[2]])


def align(
    template: Template, image: Template, guess_px: np.ndarray, *, coarsest: int = LEVELS - 1
) -> Alignment:
    """The motion from the template's frame to ``image``'s, starting at ``guess_px``.

    The motion m says frame j's pixel q shows frame i's pixel R q + t; the template's pixel
    p is therefore found in frame j at m⁻¹(p), the warp the alignment moves. A guess good
    to a pixel or two (the previous pair's motion) may start at a finer ``coarsest``
    level."""
    motion = _inverse(guess_px)
    hessian, residual, overlap = np.eye(3), np.inf, 0.0
    for level in reversed(range(coarsest + 1)):
        factor = 2.0**level
        start = np.array([motion[0] / factor, motion[1] / factor, motion[2]])
        found, hessian, residual, overlap = _align_level(
            template, level, image.images[level], start
        )
        motion = np.array([found[0] * factor, found[1] * factor, found[2]])
    # the motion and its covariance, carried through the inversion (numeric Jacobian)
    result = _inverse(motion)
    step = 1e-6
    jac = np.column_stack(
        [(_inverse(motion + step * np.eye(3)[k]) - result) / step for k in range(3)]
    )
    covariance = jac @ (residual**2 * np.linalg.pinv(hessian)) @ jac.T
    sharp = sharpness(template, image, motion)
    contrast = float(np.std(template.values[0]))
    reason = None
    if overlap < MIN_OVERLAP:
        reason = "too little overlap (too fast)"
    elif not (residual < MAX_RESIDUAL or residual < MAX_RESIDUAL_SHARE * contrast):
        reason = "the frames do not match after alignment (a changed floor)"
    warning = LOW_TEXTURE if sharp < MIN_SHARPNESS else None
    return Alignment(result, covariance, residual, overlap, sharp, reason, warning)


def seed_px(template: Template, image: Template) -> np.ndarray:
    """A start from phase correlation on the quarter-size levels (full-size pixels), the
    light's fixed pattern already out: on a faint floor the vignetting left in wins the
    correlation, and says the camera stood still."""
    factor = 2.0 ** (LEVELS - 1)
    pair = pair_motion(template.images[-1], image.images[-1])
    return np.array([pair.dx_px * factor, pair.dy_px * factor, pair.dtheta_rad])
