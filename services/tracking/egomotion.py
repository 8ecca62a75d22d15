"""The sensor's own motion between consecutive scans, for sequences without poses (a KITTI
tracking download has none; a raw drive's GPS may be missing).

The motion model predicts a target in the world; without the ego motion the world is the
sensor's frame, and a parked car the sensor drives past, once lost, stays behind at its
last place. Here each scan is registered to the previous one in the ground plane (x, y,
heading) by trimmed point-to-point ICP on what stands above the road (z between
``LOW_M`` and ``HIGH_M`` in the sensor's frame, within ``RANGE_M``: walls, poles, trees,
parked cars — the road itself is flat and says nothing about the motion along it), at
most ``TARGET_POINTS`` of the previous scan and ``SOURCE_POINTS`` of the current (evenly
through the scan), from the last motion as the guess (vehicles move smoothly) — or, for the
first pair and after a failure, from the shift (within ``SEARCH_M``) that best overlaps
the two scans' bird's-eye occupancy — the trim closing from ``TRIM_M[0]`` to
``TRIM_M[1]``. A registration that matches less than ``MIN_MATCHED`` of its points says
nothing (None: unknown).
"""

from __future__ import annotations

import numpy as np

from services.tracking.correlation import best_shift

LOW_M, HIGH_M = -1.2, 1.5
"""Heights in the sensor's frame (KITTI's HDL-64E is 1.73 m up) that stand above the road."""
RANGE_M = (3.0, 40.0)
TARGET_POINTS = 8000
SOURCE_POINTS = 1500
TRIM_M = (1.2, 0.2)
ITERATIONS = 12
MIN_MATCHED = 0.3
SEARCH_M = 4.0
"""The most a car moves in a tenth of a second (144 km/h)."""
COARSE_RANGE_M, COARSE_CELL_M = 25.0, 0.4
"""The first pair's overlap is sought among the returns this near, on cells this wide."""


def _standing(points: np.ndarray) -> np.ndarray:
    """(M, 2) the scan's standing points, x and y."""
    distance_2 = points[:, 0] ** 2 + points[:, 1] ** 2
    keep = (
        (points[:, 2] > LOW_M)
        & (points[:, 2] < HIGH_M)
        & (distance_2 > RANGE_M[0] ** 2)
        & (distance_2 < RANGE_M[1] ** 2)
    )
    return np.asarray(points[keep, :2], dtype=np.float64)


def _every(xy: np.ndarray, most: int) -> np.ndarray:
    """At most ``most`` of the points, evenly through the scan's order (a spinning sensor's
    order sweeps the scene, so they spread over it)."""
    return xy[:: max(1, -(-len(xy) // most))]


def _rigid_2d(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(θ, tx, ty) with target ≈ R(θ) source + t (least squares)."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    a, b = source - source_mean, target - target_mean
    theta = np.arctan2((a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum(), (a * b).sum())
    c, s = np.cos(theta), np.sin(theta)
    moved = np.array(
        [c * source_mean[0] - s * source_mean[1], s * source_mean[0] + c * source_mean[1]]
    )
    return np.array([theta, *(target_mean - moved)])


def as_transform(motion: np.ndarray) -> np.ndarray:
    """(θ, tx, ty) → the 4 × 4 ``prev_T_cur``, a turn about z."""
    theta, tx, ty = motion
    out = np.eye(4)
    out[:2, :2] = [[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]]
    out[:2, 3] = tx, ty
    return out


class EgoMotion:
    """Feed the scans in order; each answers ``prev_T_cur`` (None for the first, or when
    the registration says nothing)."""

    def __init__(self) -> None:
        self.tree = None
        self.guess: np.ndarray | None = None

    def __call__(self, points: np.ndarray) -> np.ndarray | None:
        from scipy.spatial import cKDTree

        standing = _standing(points)
        target = _every(standing, TARGET_POINTS)
        previous, self.tree = self.tree, cKDTree(target) if len(target) >= 10 else None
        if previous is None or self.tree is None:
            return None
        source = _every(standing, SOURCE_POINTS)
        if self.guess is None:
            # the previous scan is the current one moved by the motion: fixed = previous
            near = np.hypot(target[:, 0], target[:, 1]) < COARSE_RANGE_M
            shift = best_shift(previous.data, target[near], SEARCH_M, COARSE_CELL_M)
            self.guess = np.array([0.0, *shift])
        motion, matched = self.guess.copy(), 0
        for trim in np.geomspace(*TRIM_M, ITERATIONS):
            c, s = np.cos(motion[0]), np.sin(motion[0])
            moved = source @ np.array([[c, s], [-s, c]]) + motion[1:]
            distance, nearest = previous.query(moved, distance_upper_bound=trim)
            good = np.isfinite(distance)
            matched = int(good.sum())
            if matched < 10:
                break
            motion = _rigid_2d(source[good], previous.data[nearest[good]])
        if matched < MIN_MATCHED * len(source):
            self.guess = None
            return None
        self.guess = motion
        return as_transform(motion)
