"""vista's method: direct planar alignment of consecutive frames at full resolution.

The motion of frame j against frame i is the rigid planar warp that makes frame j,
sampled at the warped positions of frame i's textured pixels, look like frame i —
inverse-compositional Gauss–Newton on a three-level pyramid (each frame's pyramid and its
template's gradients are computed once, for both pairs it belongs to; a level's iterations
are one compiled call, ``kernels``), with the brightness's gain and offset refitted at
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

from services.lib.png import decode_grey8
from services.odometry import kernels
from services.odometry.phase import pair_motion

LEVELS = 3
POINTS_PER_LEVEL = (6_000, 4_000, 3_000)
"""Template pixels used at full, half and quarter size (the most textured ones)."""
ITERATIONS = (6, 8, 10)
CONVERGED_PX = (0.005, 0.02, 0.05)
"""A level is done when a step moves its points less than this (level pixels)."""
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
    total = np.zeros(frames[0].shape, np.float64)
    for frame in frames:  # summed in place: 200 frames as float copies took 250 MB
        total += frame
    mean = total / len(frames)
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


def prepare(image: np.ndarray, flat: np.ndarray | None = None) -> Template:
    """A frame's pyramid (divided by the light's ``flat`` field, if given), its most
    textured pixels per level and their Jacobians."""
    # cv2.divide: one pass, the same values as image.astype(np.float32) / flat
    level = image.astype(np.float32) if flat is None else cv2.divide(image, flat, dtype=cv2.CV_32F)
    images, points, values, jacobians = [], [], [], []
    for k in range(LEVELS):
        if k:
            level = cv2.pyrDown(level)
        border, stride = 4, 2 if k == 0 else 1  # at full size every other pixel competes
        candidates = len(range(border, level.shape[0] - border, stride)) * len(
            range(border, level.shape[1] - border, stride)
        )
        xy, value, jacobian = kernels.textured_points(
            level, border, stride, min(POINTS_PER_LEVEL[k], candidates // 4)
        )
        points.append(xy)
        values.append(value)
        jacobians.append(jacobian)
        images.append(level)
    return Template(images, points, values, jacobians)


def _align_level(
    template: Template, level: int, image: np.ndarray, start: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Gauss–Newton at one level from ``start`` (level pixels): the warp from template to
    ``image`` coordinates, J^T W J, the robust residual RMS and the overlap (one compiled
    call: ``kernels.align_level``)."""
    return kernels.align_level(
        image,
        template.points[level],
        template.values[level],
        template.jacobians[level],
        start.astype(np.float64),
        ITERATIONS[level],
        CONVERGED_PX[level],
    )


def sharpness(template: Template, image: Template, warp: np.ndarray) -> float:
    """How much worse the frames match one pixel off the found warp (along x and y, the
    smaller): near 0 when the floor has nothing to align on (noise matches noise
    anywhere), or only lines along one direction."""
    xy, value = template.points[0][::SHARPNESS_STRIDE], template.values[0][::SHARPNESS_STRIDE]
    return kernels.sharpness(image.images[0], xy, value, warp.astype(np.float64))


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


def warm_up() -> None:
    """Compile the alignment's and the PNG decoder's kernels, or load them from numba's
    cache (once per installation, then a fraction of a second per process), so a timing
    leaves it out: one small frame decoded from a PNG, one pair aligned."""
    floor = cv2.GaussianBlur(np.random.default_rng(0).uniform(0, 255, (64, 64)), (0, 0), 1.5)
    frame = decode_grey8(cv2.imencode(".png", floor.astype(np.uint8))[1].tobytes())
    align(prepare(frame), prepare(np.roll(frame, 1, axis=1)), np.zeros(3))


def seed_px(template: Template, image: Template) -> np.ndarray:
    """A start from phase correlation on the quarter-size levels (full-size pixels), the
    light's fixed pattern already out: on a faint floor the vignetting left in wins the
    correlation, and says the camera stood still."""
    factor = 2.0 ** (LEVELS - 1)
    pair = pair_motion(template.images[-1], image.images[-1])
    return np.array([pair.dx_px * factor, pair.dy_px * factor, pair.dtheta_rad])
