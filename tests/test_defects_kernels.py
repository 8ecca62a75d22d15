"""The fast building blocks of `vista defects measure` against plain NumPy/SciPy references: the
compiled passes over the points (binning, seam slabs, the frame's sample), square
morphology, labelling (4- and 8-connected, with boxes), what the border reaches, block
sums, block interpolation, Gaussian smoothing, a section's widest gap, the robust
reference fit and region shapes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from services.defects import binning
from services.defects.morphology import border_reach, dilate, erode, label4, label8
from services.defects.raster import SAMPLE_POINTS, block_sums, fit_frame, rasterize
from services.defects.sections import (
    MIN_POINTS,
    START_WINDOW_MM,
    _median_heights,
    _robust_plane,
    _top_sums,
    _widest_gap,
)
from services.defects.smoothing import gaussian_kernel, gaussian_pair
from services.defects.surface import (
    _below,
    _blocks,
    _depth_below_band,
    _scores,
    _shape,
    _tukey_fit,
    _upsample,
)


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
    # The height above the upsampled surface, in the same pass: as NumPy gives it, bit for bit.
    blocks, height = blocks.astype(np.float32), values.astype(np.float32)
    inside = rng.random(values.shape) < 0.7
    expected = np.where(inside, height - _upsample(blocks, 5, height.shape), np.nan)
    below = _below(height, inside, blocks, 5)
    assert below.dtype == np.float32
    np.testing.assert_array_equal(below, expected)


@pytest.mark.parametrize("shape", [(23, 17), (25, 20), (3, 4)])
def test_block_means_equal_block_sums_bit_for_bit(shape) -> None:
    """The one-pass block means of the masked cells: the float32 sums of ``block_sums``
    in its order, so the same means to the last bit (NaN where a block has none)."""
    rng = np.random.default_rng(shape[0])
    values = (rng.normal(0.0, 30.0, shape) + 1e3 * rng.random(shape)).astype(np.float32)
    mask = rng.random(shape) < 0.7
    mask[: min(5, shape[0]), : min(5, shape[1])] = False  # a block with no cell inside
    weights = mask.astype(np.float32)
    total = block_sums(np.where(weights > 0, values, 0.0) * weights, 5)
    count = block_sums(weights, 5)
    with np.errstate(invalid="ignore", divide="ignore"):
        expected = total / count
    mean, weight = _blocks(values, mask, 5)
    assert mean.dtype == weight.dtype == np.float32
    assert np.array_equal(weight, count)
    assert np.array_equal(mean, expected, equal_nan=True)
    assert np.isnan(mean[0, 0])


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("per_block", [40, binning.PACKED_MAX_POINTS + 1, 20_000])
def test_block_colours_are_exact_sums_however_dense_the_cloud(workers, per_block) -> None:
    """Each block's three colour sums, packed in one integer per point, are the exact
    sums of its points' channels; a block too full for the packing (white points beyond
    ``PACKED_MAX_POINTS``) is summed channel by channel instead."""
    rng = np.random.default_rng(per_block)
    # A 4 × 3 mm patch of 1 mm blocks (5 cells of 0.2 mm), one block per_block times over.
    spread = np.column_stack([rng.uniform(0, 4, 3000), rng.uniform(0, 3, 3000)])
    dense = rng.uniform(1.05, 1.95, (per_block, 2))
    uv = np.concatenate([spread, dense])
    points = np.column_stack([uv, np.zeros(len(uv))]).astype(np.float32)
    colors = rng.integers(0, 256, (len(points), 3)).astype(np.uint8)
    colors[3000:] = 255  # the fullest sums
    origin, axes, grid = np.zeros(3), np.eye(3), np.array([0.0, 0.0, 1 / 0.2])
    count, _, block_count, color, _ = binning.bin_points(
        points, colors, origin, axes, grid, (20, 15), 5, workers
    )
    block = (uv[:, 0] // 1.0).astype(np.int64) * 3 + (uv[:, 1] // 1.0).astype(np.int64)
    for channel in range(3):
        expected = np.bincount(block, weights=colors[:, channel], minlength=12)
        assert np.array_equal(color[:, channel], expected)
    assert block_count.max() >= per_block and count.sum() == len(points)


KITTI_SCAN = (
    Path(__file__).resolve().parents[2] / "shared/data/kitti-raw-2011_09_26/velodyne/0000000000.bin"
)


@pytest.mark.skipif(not KITTI_SCAN.is_file(), reason="../shared/data's KITTI raw drive is not here")
@pytest.mark.parametrize(("cell_mm", "workers"), [(50.0, 2), (400.0, 1)])
def test_binning_of_a_real_lidar_scan_equals_numpy(cell_mm, workers) -> None:
    """A real sensor's cloud, outside the simulator's assumptions: a spinning LiDAR's scan
    order (ring by ring), returns out to 80 m, its reflectance as colour. Counts, heights
    and colour sums per cell and per block of 5 × 5 cells equal NumPy's; at 400 mm cells
    a block holds more than ``PACKED_MAX_POINTS`` returns (on one worker: two would share
    them), so the colours take the channel-by-channel path."""
    scan = np.fromfile(KITTI_SCAN, np.float32).reshape(-1, 4)
    points = scan[:, :3] * np.float32(1000.0)  # mm
    grey = np.clip(scan[:, 3] * 255, 0, 255).astype(np.uint8)
    colors = np.stack([grey, 255 - grey, grey // 2], 1)
    frame = fit_frame(points, None)
    bounds = binning.uv_bounds(points, frame.origin, frame.axes, stride=1)
    origin_uv = np.array([bounds[0], bounds[2]]) - cell_mm
    shape = (
        int((bounds[1] - origin_uv[0]) / cell_mm) + 2,
        int((bounds[3] - origin_uv[1]) / cell_mm) + 2,
    )
    grid = np.array([*origin_uv, 1 / cell_mm])
    count, height, block_count, color, _ = binning.bin_points(
        points, colors, frame.origin, frame.axes, grid, shape, 5, workers
    )

    # In the kernel's order of operations, so that a return on a cell's edge falls alike.
    x, y, z = (points.astype(np.float64) - frame.origin).T
    local = np.stack([x * axis[0] + y * axis[1] + z * axis[2] for axis in frame.axes], 1)
    index = np.floor((local[:, :2] - origin_uv) * (1 / cell_mm)).astype(np.int64)
    expected = np.bincount(index[:, 0] * shape[1] + index[:, 1], minlength=count.size)
    assert np.array_equal(count, expected)
    heights = np.bincount(
        index[:, 0] * shape[1] + index[:, 1], weights=local[:, 2], minlength=count.size
    )
    assert np.allclose(height, heights, rtol=1e-5, atol=1.0)  # float32 sums
    block = (index[:, 0] // 5) * -(-shape[1] // 5) + index[:, 1] // 5
    per_block = np.bincount(block, minlength=block_count.size)
    assert np.array_equal(block_count, per_block)
    assert (per_block.max() > binning.PACKED_MAX_POINTS) == (cell_mm == 400.0)
    for channel in range(3):
        total = np.bincount(block, weights=colors[:, channel], minlength=per_block.size)
        assert np.array_equal(color[:, channel], total)


def test_binning_agrees_with_numpy_and_skips_strays() -> None:
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
    # threads share the points: the same cells whatever their number
    shared = rasterize(points, colors, frame, 0.5, bounds, workers=3)
    assert np.array_equal(shared.count, raster.count)
    assert np.allclose(shared.height, raster.height, equal_nan=True, atol=1e-6)
    assert np.array_equal(shared.chunk_uv, raster.chunk_uv, equal_nan=True)


def _slab_reference(
    local: np.ndarray, index: np.ndarray, line: np.ndarray, sections: np.ndarray
) -> np.ndarray:
    """(M, 4) sorted (k, y, x, w) rows of the points in one seam's slabs, by NumPy
    (``index``: each point's in the cloud)."""
    rel = local[:, :2] - line[:2]
    along = rel @ line[2:4]
    across = rel @ np.array([-line[3], line[2]])
    first, pitch, count, half_slab, reach, dense_half, dense_reach, stride = sections
    k = np.rint((along - first) / pitch)
    y = along - (first + k * pitch)
    inside = (k >= 0) & (k < count) & (np.abs(y) <= half_slab) & (np.abs(across) < reach)
    kept = index % stride == 0  # the cloud's every stride-th point…
    inside &= kept | (np.abs(y) <= dense_half) | (np.abs(across) < dense_reach)  # …or dense
    rows = np.column_stack([k, y, across, local[:, 2]])[inside]
    return rows[np.lexsort(rows.T[::-1])]


@pytest.mark.parametrize("order", ["scan", "shuffled"])
@pytest.mark.parametrize("thinned", [False, True])
def test_seam_slabs_equal_numpy_with_and_without_skipping_runs(order, thinned) -> None:
    """Every point within a slab, once per slab; a thinned slab keeps every point within
    its dense half width or reach across, and the cloud's every stride-th beyond both."""
    rng = np.random.default_rng(3)
    u, v = np.meshgrid(np.arange(0, 60, 0.1), np.arange(0, 40, 0.1), indexing="ij")
    points = np.column_stack([u.ravel(), v.ravel(), rng.normal(0, 0.05, u.size)])
    if order == "shuffled":  # every run of points spans the plate: none can be skipped
        points = points[rng.permutation(len(points))]
    points = points.astype(np.float32)
    points[:3] = np.nan
    frame = fit_frame(points, None)
    raster = rasterize(
        points, None, frame, 0.1, binning.uv_bounds(points, frame.origin, frame.axes)
    )
    local = (points[3:].astype(np.float64) - frame.origin) @ frame.axes.T
    # One seam along u, one diagonal crossing it: the cells where they meet are in both
    # bands.
    direction = np.array([1.0, 1.0]) / np.sqrt(2)
    lines = np.array(
        [
            [local[:, 0].mean(), local[:, 1].mean(), 1.0, 0.0, -25.0, 25.0],
            [local[:, 0].mean(), local[:, 1].mean(), *direction, -20.0, 20.0],
        ]
    )
    sections = np.array(
        [[-20.0, 2.0, 21, 0.5, 4.0, 0.5, 4.0, 1], [-15.0, 2.5, 13, 0.5, 3.0, 0.5, 3.0, 1]]
    )
    if thinned:  # dense within 0.2 mm of the plane or 1–1.5 mm of the line; every 7th beyond
        sections[:, 5:] = [[0.2, 1.0, 7], [0.2, 1.5, 7]]
    pieces = binning.seam_slabs(
        points,
        frame.origin,
        frame.axes,
        raster.grid,
        raster.count,
        raster.chunk_uv,
        lines,
        sections,
        workers=2 if thinned else 1,  # the second share's points keep their index
    )
    for seam in range(2):
        found = np.concatenate(pieces[seam], 1).T
        found = found[np.lexsort(found.T[::-1])]
        expected = _slab_reference(
            local, np.arange(3, len(points)), lines[seam, :4], sections[seam]
        )
        assert len(found) > 1000
        assert np.allclose(found, expected, atol=1e-9)


def _widest_gap_reference(xs: np.ndarray) -> tuple[float, float, float]:
    """The first widest stretch between consecutive sorted values, by sorting."""
    ordered = np.sort(xs)
    if len(ordered) < 2:
        return 0.0, 0.0, -1.0
    j = int(np.argmax(np.diff(ordered)))  # the first of equals
    return ordered[j], ordered[j + 1], ordered[j + 1] - ordered[j]


def test_widest_gap_without_sorting_equals_sorting() -> None:
    rng = np.random.default_rng(7)
    samples = [np.array([]), np.array([1.0]), np.array([2.0, 2.0]), np.arange(10.0)]
    for n in rng.integers(2, 80, 2000):
        kind = rng.integers(0, 4)
        if kind == 0:  # a section's points: two tops and a gap between them
            xs = np.concatenate([rng.uniform(-4, -0.4, n), rng.uniform(0.6, 4, n)])
        elif kind == 1:  # repeated values
            xs = np.round(rng.normal(0, 2, n), 1)
        elif kind == 2:  # evenly spaced to the last bit: every stretch as wide
            xs = rng.permutation(np.arange(n) * 0.25)
        else:
            xs = rng.normal(0, 1, n)
        samples.append(xs)
    for xs in samples:
        assert _widest_gap(xs) == _widest_gap_reference(xs)


@pytest.mark.parametrize("shape", [(1, 9), (9, 1), (60, 45), (0, 4)])
def test_labelling_equals_scipy(shape) -> None:
    rng = np.random.default_rng(4)
    masks = [rng.random(shape) < share for share in (0.3, 0.55, 0.8)]
    if min(shape) > 1:  # blobs: long runs along the rows, joined and split below
        masks += [ndimage.gaussian_filter(rng.normal(size=shape), 3) > level for level in (0, 0.05)]
    for mask in masks:
        labels, sizes = label4(mask)
        expected, count = ndimage.label(mask)
        assert np.array_equal(labels, expected)
        assert np.array_equal(sizes, np.bincount(expected.ravel(), minlength=count + 1)[1:])
        labels, boxes = label8(mask)
        expected, count = ndimage.label(mask, np.ones((3, 3), bool))
        assert np.array_equal(labels, expected)
        found = ndimage.find_objects(expected) if count else []
        assert [tuple(box) for box in boxes] == [
            (rows.start, cols.start, rows.stop - 1, cols.stop - 1) for rows, cols in found
        ]


@pytest.mark.parametrize("shape", [(31, 22), (1, 5), (6, 1), (2, 40)])
def test_scratch_depth_and_scores_equal_the_numpy_expressions_bit_for_bit(shape) -> None:
    """The compiled band-pass depth (smoothing and depth in one pass), its noise sample
    and the scores against the smoothing and NumPy expressions they replaced (float32;
    NaN heights outside the inside cells, and a strip of them wider than the kernel)."""
    rng = np.random.default_rng(9)
    deviation = rng.normal(0, 0.05, shape).astype(np.float32)
    inside = rng.random(shape) < 0.8
    inside[:, : shape[1] // 3] = False
    deviation[~inside] = np.nan
    background = rng.normal(0, 0.02, shape).astype(np.float32)
    relief = rng.random(shape) < 0.15
    depth, sample = _depth_below_band(deviation, inside, background, relief, gaussian_kernel(1.0))
    numerator, denominator = gaussian_pair(
        np.where(inside, deviation, 0.0), inside.astype(np.float32), 1.0
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        band = numerator / denominator - background
    clear = inside & ~relief
    expected = np.where(clear, -band, 0.0)
    assert depth.dtype == expected.dtype == np.float32
    np.testing.assert_array_equal(depth, expected)
    np.testing.assert_array_equal(sample, expected[::2, ::2][clear[::2, ::2]])
    noise = 1.4826 * float(np.nanmedian(np.abs(sample))) + 1e-3
    score, above = _scores(depth, np.float32(noise), 3.5)
    np.testing.assert_array_equal(score, depth / noise)
    np.testing.assert_array_equal(above, depth / noise > 3.5)


@pytest.mark.parametrize("shape", [(1, 9), (9, 1), (60, 45), (0, 4)])
def test_border_reach_equals_the_parts_labelling_finds_on_the_border(shape) -> None:
    rng = np.random.default_rng(6)
    for share in (0.3, 0.55, 0.8):
        mask = rng.random(shape) < share
        parts, _ = ndimage.label(mask)
        on_border = np.unique(
            np.concatenate([parts[0], parts[-1], parts[:, 0], parts[:, -1]]) if parts.size else []
        )
        expected = np.isin(parts, on_border[on_border > 0])
        assert np.array_equal(border_reach(mask), expected)


@pytest.mark.parametrize("sigma", [1.0, 2.2, 4.0])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_gaussian_pair_equals_scipy(sigma, dtype) -> None:
    rng = np.random.default_rng(5)
    for shape in ((31, 44), (3, 2), (1, 7)):  # kernels wider than the array: mirrored on
        a, b = rng.random(shape).astype(dtype), rng.random(shape).astype(dtype)
        smooth_a, smooth_b = gaussian_pair(a, b, sigma)
        assert smooth_a.dtype == dtype
        tolerance = 1e-6 if dtype == np.float32 else 1e-12
        assert np.allclose(
            smooth_a, ndimage.gaussian_filter(a, sigma, truncate=3.0), atol=tolerance
        )
        assert np.allclose(
            smooth_b, ndimage.gaussian_filter(b, sigma, truncate=3.0), atol=tolerance
        )


def test_tukey_fit_and_region_shape_equal_numpy() -> None:
    rng = np.random.default_rng(6)
    design = np.column_stack([np.ones(3000), rng.random((3000, 5))])
    target = design @ rng.normal(size=6) + rng.normal(0, 0.01, 3000)
    target[::50] += 5.0  # outliers: weighted out
    weight = np.ones(len(target))
    for _ in range(4):
        weighted = design * weight[:, None]
        coef = np.linalg.solve(weighted.T @ design + 1e-9 * np.eye(6), weighted.T @ target)
        residual = target - design @ coef
        sigma = max(1.4826 * np.median(np.abs(residual)), 1e-4)
        weight = np.clip(1 - (residual / (4.685 * sigma)) ** 2, 0.0, None) ** 2
    found, found_weight = _tukey_fit(np.ascontiguousarray(design.T), target, 4)
    assert np.allclose(found, coef, atol=1e-10) and np.allclose(found_weight, weight)
    assert (found_weight[::50] == 0).all()

    for rows, cols in [
        (rng.integers(0, 40, 300), rng.integers(0, 9, 300)),
        (np.arange(50), np.arange(50) // 2),
        (np.arange(30), np.full(30, 4)),
    ]:
        values, vectors = np.linalg.eigh(np.cov(np.stack([rows, cols]) * 0.1))
        spread = np.sqrt(np.maximum(values, 0.0) * 12) + 0.1
        length, width, direction = _shape(rows, cols, 0.1)
        assert np.isclose(length, spread[1]) and np.isclose(width, spread[0], atol=1e-6)
        assert np.isclose(abs(direction @ vectors[:, 1]), 1.0)


def test_frame_from_the_sample_equals_numpy() -> None:
    rng = np.random.default_rng(7)
    points = rng.normal(0, 1, (200_000, 3)) * [40.0, 20.0, 0.5] + [300.0, -50.0, 1000.0]
    points[::97] = np.nan
    normals = np.tile([0.0, 0.0, -1.0], (len(points), 1))
    frame = fit_frame(points.astype(np.float32), normals)
    step = len(points) // SAMPLE_POINTS
    sample = points[::step].astype(np.float32).astype(np.float64)
    sample = sample[np.isfinite(sample).all(1)]
    assert np.allclose(frame.origin, sample.mean(0), atol=1e-6)
    values, vectors = np.linalg.eigh(np.cov(sample.T))
    assert np.isclose(abs(frame.axes[0] @ vectors[:, 2]), 1.0)
    assert np.allclose(frame.axes[2], -vectors[:, 0] * np.sign(vectors[2, 0]), atol=1e-9)


def test_robust_planes_equal_the_numpy_steps_bit_for_bit() -> None:
    """The compiled robust planes against the NumPy steps they replaced (a batched solve
    of the normal equations, σ through ``np.fmax``), groups with too few points and
    outliers included."""
    rng = np.random.default_rng(12)
    groups = 9
    group = rng.integers(0, groups, 4000)
    group[group == 4] = 5  # group 4 has no point, group 7 too few
    group[np.flatnonzero(group == 7)[5:]] = 8
    x, y = rng.uniform(-3, 3, 4000), rng.uniform(-0.5, 0.5, 4000)
    w = 0.1 * group + 0.02 * x - 0.01 * y + rng.normal(0, 0.01, 4000)
    w[::37] += rng.choice([-4.0, 3.0], len(w[::37]))  # the backing, spikes
    low, high, min_abs = -2.5, 2.5, 0.2
    plane, sigma = _robust_plane(group, x, w, y, low, high, min_abs, groups)

    expected = np.zeros((groups, 3))
    expected[:, 0] = _median_heights(group, x, w, low, high, min_abs, groups)
    clip = np.full(groups, START_WINDOW_MM)
    for _ in range(2):
        sums = _top_sums(group, x, w, y, low, high, min_abs, expected, clip, groups)
        normal = np.zeros((groups, 3, 3))
        for row, (i, j) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
            normal[:, i, j] = normal[:, j, i] = sums[row]
        enough = sums[0] >= MIN_POINTS
        normal[~enough] = np.eye(3)
        normal[enough] += np.eye(3) * 1e-9 * sums[0][enough, None, None]
        expected = np.linalg.solve(normal, sums[6:9].T[..., None])[..., 0]
        expected[~enough] = np.nan
        n = np.maximum(sums[0], 1)
        with np.errstate(invalid="ignore"):
            fitted = expected[:, 0] * sums[6] + expected[:, 1] * sums[7] + expected[:, 2] * sums[8]
            explained = np.where(np.isfinite(fitted), fitted / n, np.nan)
            expected_sigma = np.sqrt(np.fmax(sums[9] / n - explained, 0))
        clip = np.where(np.isfinite(expected_sigma), np.maximum(3.0 * expected_sigma, 0.01), np.inf)
        expected = np.where(np.isfinite(expected), expected, 0.0)
    expected[~enough], expected_sigma[~enough] = np.nan, np.nan
    assert np.isnan(plane[[4, 7]]).all() and np.isfinite(plane[[0, 1, 2, 3, 5, 6, 8]]).all()
    np.testing.assert_array_equal(plane, expected)
    np.testing.assert_array_equal(sigma, expected_sigma)
