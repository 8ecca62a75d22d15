"""The fast building blocks of `vista measure` against plain NumPy/SciPy references: the
compiled passes over the points, square morphology, block sums and block interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from services.defects import binning
from services.defects.morphology import dilate, erode
from services.defects.raster import block_sums, fit_frame, rasterize
from services.defects.surface import _upsample


@pytest.mark.parametrize("shape", [(1, 7), (9, 1), (40, 33)])
@pytest.mark.parametrize("radius", [0, 1, 3, 15])
def test_square_morphology_equals_scipy(shape, radius) -> None:
    rng = np.random.default_rng(radius)
    for share in (0.1, 0.5, 0.9):
        mask = rng.random(shape) < share
        width = 2 * radius + 1
        expected = ndimage.minimum_filter(mask, width, mode="constant")
        assert np.array_equal(erode(mask, radius), expected)
        expected = ndimage.maximum_filter(mask, width, mode="constant")
        assert np.array_equal(dilate(mask, radius), expected)


def test_block_sums_and_upsampling_equal_the_references() -> None:
    rng = np.random.default_rng(1)
    values = rng.random((23, 17))
    padded = np.zeros((25, 20))
    padded[:23, :17] = values
    assert np.allclose(block_sums(values, 5), padded.reshape(5, 5, 4, 5).sum((1, 3)))
    assert block_sums(values > 0.5, 5).sum() == (values > 0.5).sum()  # booleans counted
    blocks = rng.random((5, 4))
    zoomed = ndimage.zoom(blocks, 5, order=1, mode="nearest", grid_mode=True)[:23, :17]
    assert np.allclose(_upsample(blocks, 5, (23, 17)), zoomed)


def test_binning_and_gathering_agree_with_numpy_and_skip_strays() -> None:
    rng = np.random.default_rng(2)
    points = np.column_stack(
        [rng.uniform(0, 40, 20_000), rng.uniform(0, 30, 20_000), rng.normal(0, 0.1, 20_000)]
    ).astype(np.float32)
    points[:5] = np.nan  # not finite
    points[5:8] = [[400.0, 0.0, 0.0], [0.0, -300.0, 0.0], [1e6, 1e6, 0.0]]  # far strays
    colors = rng.integers(0, 256, (len(points), 3)).astype(np.uint8)
    frame = fit_frame(points, None)
    bounds = binning.uv_bounds(points[8:], frame.origin, frame.axes)
    raster = rasterize(points, colors, frame, 0.5, bounds)

    local = (points[8:].astype(np.float64) - frame.origin) @ frame.axes.T
    index = np.floor((local[:, :2] - raster.origin_uv) / 0.5).astype(np.int64)
    flat = index[:, 0] * raster.shape[1] + index[:, 1]
    count = np.bincount(flat, minlength=raster.count.size)
    assert np.array_equal(raster.count.ravel(), count)  # the 8 bad points are left out
    height = np.bincount(flat, weights=local[:, 2], minlength=count.size)[count > 0]
    assert np.allclose(raster.height.ravel()[count > 0], height / count[count > 0], atol=1e-5)
    assert raster.block_count.sum() == len(points) - 8
    red = np.bincount(
        (index[:, 0] // 2) * raster.block_count.shape[1] + index[:, 1] // 2,
        weights=colors[8:, 0],
        minlength=raster.block_count.size,
    ).reshape(raster.block_count.shape)
    seen = raster.block_count > 0
    assert np.allclose(raster.block_rgb[..., 0][seen], red[seen] / raster.block_count[seen])

    cells = np.flatnonzero(count)[::7]
    order, offsets = raster.points_in(points, cells)
    for i in (0, len(cells) // 2, len(cells) - 1):
        inside = np.flatnonzero(flat == cells[i]) + 8
        assert np.array_equal(order[offsets[i] : offsets[i + 1]], inside)
    assert len(order) == count[cells].sum()
