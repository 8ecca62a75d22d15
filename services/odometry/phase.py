"""The classical peer: phase correlation with a Fourier–Mellin step for the rotation
(OpenCV's ``phaseCorrelate`` and ``warpPolar``), sub-pixel.

A turn of the camera turns the magnitude of the frame's spectrum by the same angle (a
shift does not change it), so the angle is found first, as a shift along the angle axis
between the two polar spectra (of the frames' centre squares); the second frame is turned back by it, and the
translation is the phase correlation of the two. Frame j's pixel q shows what frame i's
pixel R(δθ)·q + t showed (pixels about the frame's centre), so the motion in the first
camera's frame is (t · mm/px, δθ).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

ANGLE_BINS = 1440
"""Samples of the log-polar spectrum around the circle (0.25° each)."""


@dataclass(frozen=True)
class PairMotion:
    dx_px: float
    dy_px: float
    dtheta_rad: float
    response: float
    """The translation's phase-correlation peak (0–1): low when the frames do not match."""


def _window(shape: tuple[int, int]) -> np.ndarray:
    return cv2.createHanningWindow((shape[1], shape[0]), cv2.CV_32F)


def _square(image: np.ndarray) -> np.ndarray:
    """The frame's centre square: only a square image's spectrum turns with the image."""
    rows, cols = image.shape
    side = min(rows, cols)
    top, left = (rows - side) // 2, (cols - side) // 2
    return image[top : top + side, left : left + side]


def _polar_spectrum(image: np.ndarray, window: np.ndarray) -> np.ndarray:
    """The centred log-magnitude spectrum resampled on radius × angle (rows: angles). A
    linear radius: the scale does not change between frames, and a log radius or a
    high-pass lost the turn more often on the simulated floors."""
    spectrum = np.fft.fftshift(np.abs(np.fft.fft2(image * window)))
    magnitude = np.log1p(spectrum).astype(np.float32)
    side = image.shape[0]
    return cv2.warpPolar(
        magnitude,
        (side // 2, ANGLE_BINS),
        (side / 2, side / 2),
        side / 2,
        cv2.WARP_POLAR_LINEAR | cv2.INTER_LINEAR,
    )


def turned(image: np.ndarray, theta_rad: float) -> np.ndarray:
    """``image`` resampled so that its pixel p shows what pixel R(−θ)·p showed (about the
    centre): undoes a turn of the content by θ."""
    rows, cols = image.shape
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    centre = np.array([(cols - 1) / 2, (rows - 1) / 2])
    inverse = np.array([[c, s], [-s, c]])  # R(−θ): destination → source
    offset = centre - inverse @ centre
    matrix = np.column_stack([inverse, offset]).astype(np.float64)
    return cv2.warpAffine(
        image,
        matrix,
        (cols, rows),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REFLECT,
    )


def pair_motion(first: np.ndarray, second: np.ndarray) -> PairMotion:
    """The camera's motion from ``first`` to ``second`` (grey frames of one size)."""
    a = first.astype(np.float32)
    b = second.astype(np.float32)
    square = _window(_square(a).shape)
    (_, angle_shift), _ = cv2.phaseCorrelate(  # rows of the log-polar images are angles
        _polar_spectrum(_square(a), square), _polar_spectrum(_square(b), square)
    )
    window = _window(a.shape)
    theta = -angle_shift * 2 * np.pi / ANGLE_BINS
    theta = (theta + np.pi / 2) % np.pi - np.pi / 2  # the spectrum repeats every half turn
    # The angle's peak can be a wrong one on a weakly oriented floor: keep it only when the
    # frames then match better than without a turn.
    best = None
    for angle in (theta, 0.0):
        (shift_x, shift_y), response = cv2.phaseCorrelate(a, turned(b, angle), window)
        if best is None or response > best.response:
            best = PairMotion(-shift_x, -shift_y, float(angle), float(response))
    return best
