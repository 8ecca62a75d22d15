"""A car detector without learning: the ground removed, what stands on it clustered in a
bird's-eye-view grid, a box fitted to each cluster's L shape, and each cluster scored by
how much its shape is a car's.

The box fit is search-based (Zhang et al., "Efficient L-shape fitting for vehicle
detection using laser scanners", 2017, its area criterion): every heading in 1° steps over
a quarter turn spans a rectangle around the points, and the smallest is kept. A car's far
sides are hidden from the sensor, so a rectangle shorter than a car is grown away from the
sensor to a car's size. A cluster too long or too wide for a car (a car beside a wall, a
kerb, a rail) loses its dominant straight line and is clustered again.

The score multiplies what tells a car from the rest of a street (``car_likeness``):

- its seen length and width within a car's;
- its returns against what a car at that range gives (a few stray returns are not a car);
- its roof height: cars stand 1.2–1.85 m; hedges, walls, embankments and lorries rise
  higher (what rises past ``MAX_HEIGHT_M`` is cut off and would otherwise pass for a roof);
- nothing above it: returns 2.3–4 m over its cells belong to a tree, a wall or a building;
- returns near the road (bumpers, sills, wheels 0.25–0.5 m up) — a canopy, a sign or a
  wall's top floats; a car hidden behind another shows none, so it only lowers the score;
- smooth surfaces: body panels are planes within a 0.3 m voxel, foliage scatters the beams
  (the median of the voxels' smallest covariance eigenvalue over their sum).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from services.tracking.detections import Detections, empty_detections
from services.tracking.ground import Ground, estimate_ground

CELL_M = 0.2
RANGE_M = 72.0
MIN_HEIGHT_M = 0.25
MAX_HEIGHT_M = 2.8
HEADINGS = np.radians(np.arange(0.0, 90.0, 1.0))
CAR_LENGTH_M = (3.2, 5.6)
CAR_WIDTH_M = (1.4, 2.1)
TYPICAL_CAR_M = (4.0, 1.7)
MIN_POINTS = 10
ROOF_M = (1.2, 1.85)
OVERHEAD_M = (2.3, 4.0)
LOW_M = 0.5
SURFACE_VOXEL_M = 0.3
SMOOTH = 0.015
"""Surface variation of body panels (foliage's is several times this)."""
EXPECTED_RETURNS = 100_000.0
"""A car's returns at distance d (m) are about this / d² (KITTI's HDL-64E: ~670 at 13 m,
~70 at 35 m)."""


def fit_rectangle(xy: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The heading (radians, in [0, π/2)) of the smallest rectangle around the points (a
    car's roof and bonnet fill its outline: the area criterion suits a LiDAR above them),
    and that rectangle's low and high corners in the heading's frame."""
    c, s = np.cos(HEADINGS), np.sin(HEADINGS)
    along = xy[:, 0:1] * c + xy[:, 1:2] * s  # (N, K)
    across = -xy[:, 0:1] * s + xy[:, 1:2] * c
    area = np.ptp(along, axis=0) * np.ptp(across, axis=0)
    best = int(area.argmin())
    low = np.array([along[:, best].min(), across[:, best].min()])
    high = np.array([along[:, best].max(), across[:, best].max()])
    return float(HEADINGS[best]), low, high


def _grown(
    low: np.ndarray, high: np.ndarray, sensor_local: np.ndarray, minimum: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The rectangle grown to at least ``minimum`` on each axis, away from the sensor."""
    size = high - low
    short = size < minimum
    away = sensor_local < (low + high) / 2  # the sensor is on the low side: grow the high side
    low = np.where(short & ~away, high - minimum, low)
    high = np.where(short & away, low + minimum, high)
    return low, high


def _box(points: np.ndarray, bottom_m: float) -> tuple[np.ndarray, float]:
    """A car-shaped box around a cluster (N, 3) and how plausible its size is (0–1)."""
    centre = points[:, :2].mean(axis=0)
    heading, low, high = fit_rectangle(points[:, :2] - centre)
    c, s = np.cos(heading), np.sin(heading)
    sensor = np.array([c * -centre[0] + s * -centre[1], -s * -centre[0] + c * -centre[1]])
    seen = high - low
    # the longer seen side is the car's length, unless it is too short to be one
    long_axis = 0 if seen[0] >= seen[1] else 1
    if seen[long_axis] < CAR_WIDTH_M[1] + 0.1:  # one end seen only: its across side is the width
        long_axis = 1 - long_axis
    minimum = np.empty(2)
    minimum[long_axis], minimum[1 - long_axis] = TYPICAL_CAR_M
    low, high = _grown(low, high, sensor, np.minimum(minimum, np.maximum(high - low, minimum)))
    middle = (low + high) / 2
    size = high - low
    length, width = size[long_axis], size[1 - long_axis]
    yaw = heading + (0.0 if long_axis == 0 else np.pi / 2)
    top = points[:, 2].max()
    height = top - bottom_m
    box = np.array(
        [centre[0] + c * middle[0] - s * middle[1], centre[1] + s * middle[0] + c * middle[1],
         bottom_m + height / 2, length, width, height, np.arctan2(np.sin(yaw), np.cos(yaw))]
    )  # fmt: skip
    plausible = _within(seen[long_axis], 0.0, CAR_LENGTH_M[1], 0.6) * _within(
        seen[1 - long_axis], 0.0, CAR_WIDTH_M[1] + 0.2, 0.3
    )
    return box, plausible


def _within(value: float, low: float, high: float, soft: float) -> float:
    """1 inside [low, high], falling linearly to 0 ``soft`` beyond either end."""
    return float(np.clip(1 - max(low - value, value - high, 0.0) / soft, 0.0, 1.0))


def _clusters(xy: np.ndarray) -> list[np.ndarray]:
    """Indices of the points (N, 2) of each connected group of occupied ``CELL_M`` cells
    (neighbours and their neighbours joined: a dilation closes a ring's gaps)."""
    origin = xy.min(axis=0)
    cell = np.floor((xy - origin) / CELL_M).astype(np.int64)
    occupied = np.zeros(tuple(cell.max(axis=0) + 1), dtype=bool)
    occupied[cell[:, 0], cell[:, 1]] = True
    labels, count = ndimage.label(ndimage.binary_dilation(occupied), structure=np.ones((3, 3)))
    point_label = labels[cell[:, 0], cell[:, 1]]
    order = np.argsort(point_label, kind="stable")
    bounds = np.searchsorted(point_label[order], np.arange(1, count + 2))
    return [order[bounds[k] : bounds[k + 1]] for k in range(count)]


def _line_inliers(xy: np.ndarray, rng: np.random.Generator, tolerance_m: float = 0.2) -> np.ndarray:
    """(N,) bool: the points on the cluster's dominant straight line (a wall, a kerb, a
    rail or a fence a car stands beside), found by RANSAC."""
    picks = rng.integers(0, len(xy), size=(96, 2))
    direction = xy[picks[:, 1]] - xy[picks[:, 0]]
    length = np.linalg.norm(direction, axis=1)
    good = length > 1.0
    if not good.any():
        return np.zeros(len(xy), dtype=bool)
    normal = np.column_stack([-direction[good, 1], direction[good, 0]]) / length[good, None]
    distance = np.abs(np.einsum("nkd,kd->nk", xy[:, None, :] - xy[picks[good, 0]][None], normal))
    best = int((distance < tolerance_m).sum(axis=0).argmax())
    return distance[:, best] < tolerance_m


def _too_big(xy: np.ndarray) -> bool:
    _, low, high = fit_rectangle(xy - xy.mean(axis=0))
    seen = np.sort(high - low)
    return bool(seen[1] > CAR_LENGTH_M[1] + 0.6 or seen[0] > CAR_WIDTH_M[1] + 0.3)


def _split(
    xy: np.ndarray, members: np.ndarray, rng: np.random.Generator, depth: int = 0
) -> list[np.ndarray]:
    """A cluster too big for a car: its dominant line taken out (when it has one) and the
    rest clustered again."""
    if not _too_big(xy[members]):
        return [members]
    if depth >= 3 or len(members) < 20:
        return []
    on_line = _line_inliers(xy[members], rng)
    if on_line.sum() < 0.2 * len(members) or np.ptp(xy[members[on_line]], axis=0).max() < 2.5:
        return []
    rest = members[~on_line]
    if len(rest) < MIN_POINTS:
        return []
    return [
        piece for group in _clusters(xy[rest]) for piece in _split(xy, rest[group], rng, depth + 1)
    ]


def _cell_keys(xy: np.ndarray) -> np.ndarray:
    cells = np.floor(xy / CELL_M).astype(np.int64)
    return cells[:, 0] * 1_000_003 + cells[:, 1]


def surface_variation(points: np.ndarray) -> float:
    """The median over ``SURFACE_VOXEL_M`` voxels (of at least 5 returns) of the smallest
    eigenvalue of their returns' covariance over the sum of the three: 0 on a plane, ⅓ in a
    scattering volume; NaN when no voxel has enough returns."""
    keys = np.floor(points / SURFACE_VOXEL_M).astype(np.int64)
    keys -= keys.min(axis=0)
    span = keys.max(axis=0) + 1
    _, inverse, counts = np.unique(
        (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2],
        return_inverse=True,
        return_counts=True,
    )
    inverse = inverse.ravel()
    enough = counts >= 5
    if not enough.any():
        return float("nan")
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, points)
    spread = points - (sums / counts[:, None])[inverse]
    covariance = np.zeros((len(counts), 3, 3))
    np.add.at(covariance, inverse, spread[:, :, None] * spread[:, None, :])
    values = np.linalg.eigvalsh(covariance[enough] / counts[enough, None, None])
    return float(np.median(values[:, 0] / np.maximum(values.sum(axis=1), 1e-12)))


def car_likeness(heights_m: np.ndarray, overhead_share: float, variation: float) -> float:
    """0–1: how much a cluster's shape is a car's (see the module's note), from its returns'
    heights over the road (M,), the share of them under returns 2.3–4 m up, and its
    ``surface_variation``."""
    roof = _within(float(np.percentile(heights_m, 98)), *ROOF_M, 0.35)
    clear = 1.0 / (1.0 + 3.0 * overhead_share)
    low = 0.4 + 0.6 * min(1.0, float((heights_m < LOW_M).mean()) / 0.1)
    smooth = (
        1.0
        if not np.isfinite(variation)
        else float(np.clip(1 - (variation - SMOOTH) / 0.035, 0.3, 1))
    )
    return roof * clear * low * smooth


def detect_cars(
    points: np.ndarray, ground: Ground | None = None, *, region: np.ndarray | None = None
) -> Detections:
    """Cars in a scan (N, ≥3), metres, LiDAR frame. ``region`` (x0, y0, x1, y1) limits the
    search to a window of the bird's-eye view (the tracker's resets look near the target)."""
    xyz = np.asarray(points[:, :3], dtype=np.float64)
    ground = ground or estimate_ground(xyz)
    height = ground.height(xyz)
    keep = (height > MIN_HEIGHT_M) & (height < MAX_HEIGHT_M)
    keep &= (np.abs(xyz[:, 0]) < RANGE_M) & (np.abs(xyz[:, 1]) < RANGE_M)
    if region is not None:
        x0, y0, x1, y1 = region
        keep &= (xyz[:, 0] >= x0) & (xyz[:, 0] <= x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)
    standing, above = xyz[keep], height[keep]
    if len(standing) < 5:
        return empty_detections()
    overhead = (height > OVERHEAD_M[0]) & (height < OVERHEAD_M[1])
    overhead_cells = np.unique(_cell_keys(xyz[overhead, :2]))
    rng = np.random.default_rng(0)
    pieces = [
        piece
        for group in _clusters(standing[:, :2])
        if len(group) >= MIN_POINTS
        for piece in _split(standing[:, :2], group, rng)
    ]
    boxes, scores, sizes = [], [], []
    for members in pieces:
        if len(members) < MIN_POINTS or np.ptp(standing[members, :2], axis=0).max() < 0.8:
            continue
        cluster = standing[members]
        bottom = float((cluster[:, 2] - above[members]).mean())
        box, plausible = _box(cluster, bottom)
        distance = np.hypot(box[0], box[1])
        expected = EXPECTED_RETURNS / max(distance, 5.0) ** 2
        density = min(1.0, len(members) / (0.5 * expected))
        score = plausible * density
        if score <= 0.05:
            continue
        under = np.isin(_cell_keys(cluster[:, :2]), overhead_cells).mean()
        score *= car_likeness(above[members], float(under), surface_variation(cluster))
        if score <= 0.05:
            continue
        boxes.append(box)
        scores.append(score)
        sizes.append(len(members))
    if not boxes:
        return empty_detections()
    return Detections(np.array(boxes), np.array(scores), np.array(sizes))


class GeometricDetector:
    """``detect_cars`` as the pipeline's detector branch (boxes scored at least
    ``threshold``)."""

    name = "geometric"

    def __init__(self, threshold: float = 0.5) -> None:
        self.threshold = threshold

    def detect(self, points: np.ndarray, region: np.ndarray | None = None) -> Detections:
        if region is not None:
            x0, y0, x1, y1 = region
            near = (
                (points[:, 0] >= x0 - 2)
                & (points[:, 0] <= x1 + 2)
                & (points[:, 1] >= y0 - 2)
                & (points[:, 1] <= y1 + 2)
            )
            points = points[near]
        found = detect_cars(points, region=region)
        return found.select(found.scores >= self.threshold)
