"""Where one set of bird's-eye points best overlaps another: the shift of an FFT
cross-correlation of their occupancy rasters — the coarse start of a registration that has
no guess (a tracker's first frames, the first pair of scans of a drive)."""

from __future__ import annotations

import numpy as np


def best_shift(
    moving_xy: np.ndarray, fixed_xy: np.ndarray, radius_m: float, cell_m: float
) -> np.ndarray:
    """(dx, dy), at most ``radius_m`` long, such that ``fixed_xy`` (M, 2) moved by it best
    overlaps ``moving_xy`` (N, 2) (metres; both about the origin) on a grid of ``cell_m``."""
    reach = np.abs(fixed_xy).max(axis=0) + radius_m
    size = np.ceil(2 * reach / cell_m).astype(int) + 1

    def raster(xy: np.ndarray) -> np.ndarray:
        cells = np.floor((xy + reach) / cell_m).astype(int)
        keep = ((cells >= 0) & (cells < size)).all(axis=1)
        grid = np.zeros(size)
        np.add.at(grid, (cells[keep, 0], cells[keep, 1]), 1.0)
        return np.minimum(grid, 3.0)

    # zero-padded, so the correlation does not wrap: score[shift] is the overlap of the
    # moving raster with the fixed one moved by that shift
    padded = 2 * size
    spectrum = np.fft.rfft2(raster(moving_xy), padded) * np.conj(
        np.fft.rfft2(raster(fixed_xy), padded)
    )
    full = np.fft.irfft2(spectrum, padded)
    centre = size // 2
    score = np.roll(full, tuple(centre), axis=(0, 1))[: size[0], : size[1]]
    ij = np.stack(np.meshgrid(np.arange(size[0]), np.arange(size[1]), indexing="ij"), axis=-1)
    offset = (ij - centre) * cell_m
    score = np.where(np.linalg.norm(offset, axis=-1) <= radius_m, score, -np.inf)
    best = np.unravel_index(int(np.argmax(score)), score.shape)
    return offset[best]
