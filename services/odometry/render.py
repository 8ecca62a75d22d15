"""Frames of the floor camera: the floor seen from each pose, with what a real camera adds.

A frame averages renders at poses spread over the exposure, about one per pixel of motion
(blur along the motion), each a bilinear look-up of the floor (wrapped: the floor tiles the plane) at the
pixel's floor point; the floor is first low-passed to the pixel's footprint so nothing
aliases. Then defocus (the height off the focused 110 mm), vignetting, the gain and a soft
moving shadow, shot and read noise, and 8 bits.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from services.odometry import se2
from services.odometry.camera import FloorCamera
from services.odometry.drive import Motion
from services.odometry.floors import Floor

MAX_SUBFRAMES = 48


@dataclass(frozen=True)
class Effects:
    exposure_ms: float = 1.0
    """Shutter time: blur along the motion."""
    gain_swing: float = 0.0
    """Illumination changing by ± this fraction (slowly, and in steps)."""
    vignetting: float = 0.25
    """Fraction of light lost in the corners."""
    shadow: float = 0.0
    """Depth of a soft shadow sweeping across the floor (0–1)."""
    noise: float = 1.0
    """Sensor noise scale: 1 = a typical small sensor (shot + 1.5 grey levels read)."""
    height_swing_mm: float = 0.0
    """The camera's height changes by ± this (suspension, floor bumps): scale and focus."""
    brightness: float = 0.85
    """Mean exposure: 1 puts an albedo of 1 at full scale."""


@dataclass(frozen=True)
class Exposure:
    """The frame-by-frame conditions drawn for a sequence."""

    height_mm: np.ndarray
    """(F,) camera height over the floor."""
    gain: np.ndarray
    """(F,) illumination factor."""
    shadow_at: np.ndarray
    """(F,) where the shadow's edge crosses the frame (fraction of the width; ±∞ none)."""


def exposures(
    camera: FloorCamera, times_s: np.ndarray, effects: Effects, rng: np.random.Generator
) -> Exposure:
    """The height, light and shadow of each frame: slow waves with random phases, and the
    light also in steps (a lamp switching)."""
    phase = rng.uniform(0, 2 * np.pi, size=4)
    height = camera.height_mm + effects.height_swing_mm * (
        0.7 * np.sin(2 * np.pi * 0.7 * times_s + phase[0])
        + 0.3 * np.sin(2 * np.pi * 3.1 * times_s + phase[1])
    )
    slow = np.sin(2 * np.pi * 0.2 * times_s + phase[2])
    steps = np.where(np.sin(2 * np.pi * 0.13 * times_s + phase[3]) > 0.6, 1.0, -1.0)
    gain = 1.0 + effects.gain_swing * (0.6 * slow + 0.4 * steps)
    sweep = (times_s % 4.0) / 4.0 * 3.0 - 1.0  # the edge crosses every 4 s
    shadow_at = np.where(effects.shadow > 0, sweep, np.inf)
    return Exposure(height, gain, shadow_at)


def _prefiltered(floor: Floor, camera: FloorCamera) -> np.ndarray:
    """The floor low-passed to a pixel's footprint (a Gaussian of 0.45 pixel)."""
    sigma_texels = 0.45 * camera.mm_per_px / floor.texel_mm
    return ndimage.gaussian_filter(floor.albedo, sigma_texels, mode="wrap", truncate=3.0)


def render(
    floor: Floor,
    camera: FloorCamera,
    motion: Motion,
    times_s: np.ndarray,
    effects: Effects,
    rng: np.random.Generator,
    exposure: Exposure | None = None,
) -> Iterator[np.ndarray]:
    """uint8 (height, width) frames at ``times_s`` along ``motion``."""
    exposure = exposure or exposures(camera, times_s, effects, rng)
    albedo = _prefiltered(floor, camera)
    cols = np.arange(camera.width, dtype=np.float64) - (camera.width - 1) / 2
    rows = np.arange(camera.height, dtype=np.float64) - (camera.height - 1) / 2
    across, down = np.meshgrid(cols, rows)
    radius2 = (across**2 + down**2) / ((camera.width / 2) ** 2 + (camera.height / 2) ** 2)
    vignette = (1 - effects.vignetting * radius2).astype(np.float32)
    period = np.array([albedo.shape[1], albedo.shape[0]], float)
    half_diagonal = np.hypot(camera.width, camera.height) / 2
    exposure_s = effects.exposure_ms / 1000
    for k, t in enumerate(times_s):
        start, end = motion.at(np.array([t - exposure_s / 2, t + exposure_s / 2]))
        blur_px = (
            np.hypot(*(end[:2] - start[:2])) / camera.mm_per_px
            + abs(se2.wrap(end[2] - start[2])) * half_diagonal
        )
        count = int(np.clip(np.ceil(1.5 * blur_px), 2, MAX_SUBFRAMES))
        offsets = (np.arange(count) + 0.5) / count - 0.5
        scale = camera.mm_per_px * exposure.height_mm[k] / camera.height_mm / floor.texel_mm
        image = np.zeros((camera.height, camera.width), np.float32)
        for pose in motion.at(t + offsets * exposure_s):
            c, s = np.cos(pose[2]) * scale, np.sin(pose[2]) * scale
            # wrap the pose (not each pixel) into the tile: float32 maps stay exact
            u0 = pose[0] / floor.texel_mm % period[0]
            v0 = pose[1] / floor.texel_mm % period[1]
            map_x = (u0 + c * across - s * down).astype(np.float32)
            map_y = (v0 + s * across + c * down).astype(np.float32)
            image += cv2.remap(albedo, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        image /= count
        defocus = 0.12 * abs(exposure.height_mm[k] - camera.height_mm)
        if defocus > 0.05:
            image = cv2.GaussianBlur(image, (0, 0), defocus)
        light = vignette * np.float32(exposure.gain[k] * effects.brightness)
        if np.isfinite(exposure.shadow_at[k]):
            edge = (across / camera.width - exposure.shadow_at[k] + 0.3 * down / camera.height) * 8
            light = light * (1 - effects.shadow / (1 + np.exp(-edge))).astype(np.float32)
        signal = 255.0 * image * light
        if effects.noise > 0:
            sigma = effects.noise * np.sqrt(0.05 * signal + 1.5**2)
            signal = signal + sigma * rng.standard_normal(signal.shape, dtype=np.float32)
        yield np.clip(np.rint(signal), 0, 255).astype(np.uint8)
