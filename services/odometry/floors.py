"""Floors for the simulated camera: an albedo texture (0–1) on a fine grid that tiles the
plane without seams.

Procedural floors are shaped noise made in the Fourier domain, so they are periodic by
construction; an image floor (a file, or scikit-image's CC0 brick, gravel and grass) is
mirrored into a periodic tile. One texel is ``TEXEL_MM`` of floor; a tile is
``TILE_TEXELS`` texels on a side (409.6 mm: larger than the camera's field).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import fft

TEXEL_MM = 0.1
TILE_TEXELS = 4096
PROCEDURAL = ("concrete", "asphalt", "tiles", "wood", "epoxy", "worn", "low-texture")
SAMPLE_IMAGES = ("brick", "gravel", "grass")
"""scikit-image's CC0 floor-like images (``skimage.data``)."""
IMAGE_MM_PER_PX = 0.3
"""How much floor an image floor's pixel covers unless told."""


@dataclass(frozen=True)
class Floor:
    name: str
    albedo: np.ndarray
    """(rows, columns) float32 in 0–1, periodic along both axes; row = y, column = x."""
    texel_mm: float = TEXEL_MM


def _frequencies(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Cycles per mm along x (columns, rfft half) and y (rows)."""
    fy = fft.fftfreq(n, d=TEXEL_MM)[:, None]
    fx = fft.rfftfreq(n, d=TEXEL_MM)[None, :]
    return fx, fy


def shaped_noise(
    rng: np.random.Generator,
    n: int,
    *,
    beta: float = 0.0,
    band_mm: tuple[float, float] = (0.2, 1000.0),
    stretch: tuple[float, float] = (1.0, 1.0),
) -> np.ndarray:
    """Periodic (n, n) noise of zero mean and unit deviation whose power falls as
    f^−beta within wavelengths ``band_mm`` (a smooth band); ``stretch`` (along x, y)
    lengthens its features along an axis (wood grain)."""
    white = rng.standard_normal((n, n), dtype=np.float32)
    spectrum = fft.rfft2(white, workers=-1)
    fx, fy = _frequencies(n)
    f = np.hypot(fx * stretch[0], fy * stretch[1])
    f[0, 0] = 1.0 / band_mm[1]
    shortest, longest = band_mm
    gain = f ** (-beta / 2)
    gain = gain * np.exp(-((f * shortest) ** 2)) * (1 - np.exp(-((f * longest) ** 2)))
    gain[0, 0] = 0.0
    noise = fft.irfft2(spectrum * gain.astype(np.float32), s=(n, n), workers=-1)
    return ((noise - noise.mean()) / (noise.std() + 1e-12)).astype(np.float32)


def _grid_lines(n: int, pitch_texels: int, width_texels: float, soft_texels: float) -> np.ndarray:
    """(n,) 1 on lines every ``pitch_texels`` (of ``width_texels``, soft edges), 0 between."""
    position = np.arange(n) % pitch_texels
    distance = np.minimum(position, pitch_texels - position)
    return np.clip((width_texels / 2 - distance) / soft_texels + 0.5, 0, 1).astype(np.float32)


def _concrete(rng: np.random.Generator, n: int, contrast: float = 1.0) -> np.ndarray:
    cloudy = shaped_noise(rng, n, beta=1.6, band_mm=(0.5, 200.0))
    aggregate = shaped_noise(rng, n, band_mm=(0.25, 3.0))
    pores = shaped_noise(rng, n, band_mm=(0.3, 2.0)) > 2.6
    albedo = 0.55 + contrast * (0.05 * cloudy + 0.07 * aggregate) - contrast * 0.25 * pores
    return albedo


def _asphalt(rng: np.random.Generator, n: int) -> np.ndarray:
    stones = shaped_noise(rng, n, band_mm=(0.8, 5.0))
    grains = np.clip((stones - 0.3) * 1.5, 0, 1)
    fine = shaped_noise(rng, n, band_mm=(0.15, 0.8))
    return 0.22 + 0.35 * grains + 0.05 * fine


def _tiles(rng: np.random.Generator, n: int) -> np.ndarray:
    pitch = n // 4
    per_tile = rng.normal(0.0, 0.03, size=(4, 4)).astype(np.float32)
    tile_of = np.arange(n) // pitch
    shade = per_tile[tile_of[:, None], tile_of[None, :]]
    glaze = 0.012 * shaped_noise(rng, n, band_mm=(0.2, 20.0))
    grout = np.maximum(_grid_lines(n, pitch, 30, 3)[:, None], _grid_lines(n, pitch, 30, 3)[None])
    tile = 0.72 + shade + glaze
    grout_albedo = 0.35 + 0.04 * shaped_noise(rng, n, band_mm=(0.2, 2.0))
    return tile * (1 - grout) + grout_albedo * grout


def _wood(rng: np.random.Generator, n: int) -> np.ndarray:
    plank = n // 4  # planks 102.4 mm wide along x
    grain = shaped_noise(rng, n, beta=1.0, band_mm=(0.2, 60.0), stretch=(0.05, 1.0))
    figure = shaped_noise(rng, n, band_mm=(2.0, 40.0), stretch=(0.1, 1.0))
    row = np.arange(n) // plank
    tone = rng.normal(0.0, 0.05, size=4).astype(np.float32)[row][:, None]
    seams = _grid_lines(n, plank, 4, 2)[:, None]
    joints = np.zeros((n, n), np.float32)
    offsets = rng.integers(0, n, size=4)
    columns = np.arange(n)
    for r in range(4):  # staggered plank ends: one per row of the tile (four rows)
        gap = np.abs(((columns - offsets[r]) + n // 2) % n - n // 2) < 3
        joints[r * plank : (r + 1) * plank, gap] = 1.0
    lines = np.maximum(seams, joints)
    return (0.5 + tone + 0.06 * grain + 0.03 * figure) * (1 - 0.6 * lines)


def _epoxy(rng: np.random.Generator, n: int) -> np.ndarray:
    base = 0.55 + 0.015 * shaped_noise(rng, n, beta=1.5, band_mm=(1.0, 200.0))
    chips = shaped_noise(rng, n, band_mm=(0.3, 1.5))
    flake = chips > 1.6
    chip_tone = 0.25 + 0.6 * (shaped_noise(rng, n, band_mm=(0.5, 3.0)) > 0)
    return np.where(flake, chip_tone, base)


def _low_texture(rng: np.random.Generator, n: int) -> np.ndarray:
    return 0.6 + 0.006 * shaped_noise(rng, n, beta=1.2, band_mm=(0.3, 100.0))


def procedural_floor(name: str, seed: int = 0, n: int = TILE_TEXELS) -> Floor:
    """A procedural floor (``PROCEDURAL``): the same name and seed give the same floor."""
    rng = np.random.default_rng(seed)
    makers = {
        "concrete": _concrete,
        "asphalt": _asphalt,
        "tiles": _tiles,
        "wood": _wood,
        "epoxy": _epoxy,
        "worn": lambda r, k: (
            _concrete(r, k, contrast=0.3)
            + 0.04 * shaped_noise(r, k, beta=2.0, band_mm=(5.0, 300.0))
        ),
        "low-texture": _low_texture,
    }
    if name not in makers:
        raise ValueError(f"unknown floor {name!r}; known: {', '.join(PROCEDURAL + SAMPLE_IMAGES)}")
    return Floor(name, np.clip(makers[name](rng, n), 0.02, 1.0).astype(np.float32))


def image_floor(source: str | Path, mm_per_px: float = IMAGE_MM_PER_PX) -> Floor:
    """A floor from a picture (a file, or a name in ``SAMPLE_IMAGES``) whose pixel covers
    ``mm_per_px``: grey, mirrored into a seamless tile, resampled to the texel grid."""
    import cv2

    if str(source) in SAMPLE_IMAGES:
        from skimage import data

        image = getattr(data, str(source))()
        name = str(source)
    else:
        path = Path(source)
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"{path}: not an image file OpenCV can read")
        name = path.name
    grey = image.astype(np.float32)
    if grey.ndim == 3:
        grey = grey[..., :3].mean(axis=2)
    grey /= 65535.0 if image.dtype == np.uint16 else 255.0
    if min(grey.shape) < 16:
        raise ValueError(f"{name}: {grey.shape[1]} × {grey.shape[0]} pixels is too small a floor")
    mirrored = np.block([[grey, grey[:, ::-1]], [grey[::-1], grey[::-1, ::-1]]])
    size = (
        int(round(mirrored.shape[1] * mm_per_px / TEXEL_MM)),
        int(round(mirrored.shape[0] * mm_per_px / TEXEL_MM)),
    )
    albedo = cv2.resize(mirrored, size, interpolation=cv2.INTER_CUBIC)
    return Floor(name, np.clip(albedo, 0.02, 1.0).astype(np.float32))


def make_floor(name_or_path: str, seed: int = 0, mm_per_px: float = IMAGE_MM_PER_PX) -> Floor:
    """A procedural floor by name, a sample image by name, or an image file (each of its
    pixels ``mm_per_px`` of floor)."""
    if name_or_path in PROCEDURAL:
        return procedural_floor(name_or_path, seed)
    if name_or_path in SAMPLE_IMAGES or Path(name_or_path).is_file():
        return image_floor(name_or_path, mm_per_px)
    raise ValueError(
        f"--floor {name_or_path!r}: not a floor name ({', '.join(PROCEDURAL + SAMPLE_IMAGES)}) "
        "nor an image file"
    )
