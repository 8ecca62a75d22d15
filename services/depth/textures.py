"""Procedural textures for the driving-scene simulator, evaluated at surface points.

Every texture is a function of where a ray hit the surface (metres, in the surface's own
coordinates), never of the pixel, so the left and right cameras and consecutive frames see
the same texture on the same surface — what a photometric loss needs. Noise is filtered by
the pixel's footprint on the surface (metres per pixel there): octaves finer than a pixel
are faded out instead of aliasing into speckle on distant road.
"""

from __future__ import annotations

import numpy as np

_TABLE = 1024
_LATTICE: list[np.ndarray] = []


def _lattice() -> np.ndarray:
    """Fixed random values on a periodic ``_TABLE`` × ``_TABLE`` lattice (made once)."""
    if not _LATTICE:
        _LATTICE.append(np.random.default_rng(7).random((_TABLE, _TABLE), dtype=np.float32))
    return _LATTICE[0]


def value_noise(u: np.ndarray, v: np.ndarray, seed: int) -> np.ndarray:
    """Smooth noise in 0–1 with features one unit apart at points (u, v) (any shape); each
    seed reads the shared lattice from its own offset."""
    lattice = _lattice()
    mixed = (int(seed) * 2654435761) % (1 << 32)
    u = u + float(mixed % _TABLE)
    v = v + float((mixed >> 10) % _TABLE)
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = (u - u0).astype(np.float32), (v - v0).astype(np.float32)
    fu, fv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)
    i0 = u0.astype(np.int64) % _TABLE
    j0 = v0.astype(np.int64) % _TABLE
    i1, j1 = (i0 + 1) % _TABLE, (j0 + 1) % _TABLE
    top = lattice[j0, i0] * (1 - fu) + lattice[j0, i1] * fu
    bottom = lattice[j1, i0] * (1 - fu) + lattice[j1, i1] * fu
    return top * (1 - fv) + bottom * fv


def fbm(
    u: np.ndarray,
    v: np.ndarray,
    *,
    seed: int,
    scale_m: float,
    footprint_m: np.ndarray,
    octaves: int = 5,
) -> np.ndarray:
    """Fractal noise of zero mean (about ±0.5) whose coarsest features are ``scale_m``
    across, each octave half the size and half the amplitude; an octave is faded out where
    its features are smaller than two pixels' ``footprint_m``."""
    total = np.zeros(np.shape(u), np.float32)
    size_m, amplitude = scale_m, 0.5
    for octave in range(octaves):
        visible = np.clip(size_m / (2 * footprint_m) - 1, 0, 1).astype(np.float32)
        if visible.any():
            noise = value_noise(u / size_m, v / size_m, seed + 101 * octave)
            total += amplitude * visible * (noise - 0.5) * 2
        size_m, amplitude = size_m / 2, amplitude / 2
    return total


def grid_lines(
    u: np.ndarray, period_m: float, width_m: float, footprint_m: np.ndarray
) -> np.ndarray:
    """0–1 coverage of lines ``width_m`` wide every ``period_m`` along u, blurred by the
    pixel's footprint (a line thinner than a pixel fades instead of flickering)."""
    distance = np.abs((u / period_m + 0.5) % 1.0 - 0.5) * period_m
    blur = np.maximum(footprint_m, 1e-4)
    coverage = np.clip((width_m / 2 - distance) / blur + 0.5, 0, 1)
    return coverage * np.clip(width_m / blur, 0, 1).astype(np.float32)


def boxes(
    u: np.ndarray,
    v: np.ndarray,
    *,
    period_m: tuple[float, float],
    size_m: tuple[float, float],
    offset_m: tuple[float, float],
    footprint_m: np.ndarray,
) -> np.ndarray:
    """0–1 coverage of a grid of rectangles (windows): ``size_m`` wide and high every
    ``period_m``, the first starting at ``offset_m``, edges blurred by the footprint."""
    coverage = np.ones(np.shape(u), np.float32)
    blur = np.maximum(footprint_m, 1e-4)
    for coordinate, period, size, offset in zip((u, v), period_m, size_m, offset_m, strict=True):
        local = (coordinate - offset) % period
        inside = np.minimum(local, size - local)
        coverage *= np.clip(inside / blur + 0.5, 0, 1).astype(np.float32)
    return coverage
