"""What every single-object tracker here shares: the step it answers, the motion model it
predicts with, and the point model it keeps of its target.

The motion model is constant velocity in the world: with the ego car's poses (KITTI's
``poses.txt``, or whatever moves the scans) the target's box lives in the first scan's
frame, so the ego car's own motion is not mistaken for the target's; without them the
world is the sensor's frame and the velocity is the relative one.

The point model is the target's points in its box's frame (x along its heading, origin at
its centre), merged in 10 cm voxels: the first frame's (the given box) and those of the
last frames the tracker trusted — the thesis's "model point cloud obtained by aggregating
the cropped points", kept to a window so that its errors do not accumulate.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from services.lib.boxes import YAW, H, L, W, to_box_frame, transform_boxes, wrap

VOXEL_M = 0.1
MODEL_POINTS = 4000
RECENT_FRAMES = 10
VELOCITY_GAIN = 0.5
"""How much of a new frame's motion enters the velocity (an α filter)."""
MAX_STEP_M = 4.0
MAX_TURN_RAD = 0.35
"""The most a car moves and turns in the world between two frames (40 m/s, 200°/s)."""


@dataclass(frozen=True)
class TrackStep:
    box: np.ndarray
    """(7,) the target's box in the current scan's frame."""
    confidence: float
    """0–1: how much the tracker trusts this frame's answer."""
    points: int
    """Returns inside the box."""
    predicted: np.ndarray
    """(7,) where the motion model expected the target."""


class Tracker(Protocol):
    name: str
    sigma_m: float
    """Its centre's error when it is sure of its answer (m): a reset weighs its box by it."""

    def start(self, points: np.ndarray, box: np.ndarray) -> None:
        """Begin on ``points`` (N, ≥3) with the target's ``box`` given."""
        ...

    def step(self, points: np.ndarray, prev_T_cur: np.ndarray | None) -> TrackStep:
        """The target in the next scan; ``prev_T_cur`` the ego motion since the last one
        (None: unknown)."""
        ...

    def reset(self, points: np.ndarray, box: np.ndarray) -> np.ndarray:
        """Take ``box`` (a detection fused with the tracker's own) as the target's in the
        current scan; the box the tracker holds now."""
        ...

    def appearance(self, points: np.ndarray, box: np.ndarray) -> float:
        """0–1: how much the points in ``box`` look like the target."""
        ...


class MotionModel:
    """Constant velocity (x, y, heading) of the target's box in the world frame."""

    def __init__(self, box: np.ndarray) -> None:
        self.world_T_cur = np.eye(4)
        self.world_box = np.asarray(box, dtype=np.float64).copy()
        self.velocity = np.zeros(3)
        """(vx, vy, yaw rate) per frame, world frame."""
        self.trusted_box = self.world_box.copy()
        """The last box whose motion was learnt (world frame)."""
        self.unsure_frames = 0
        """Frames since then."""

    def advance(self, prev_T_cur: np.ndarray | None) -> np.ndarray:
        """Move the sensor by the ego motion and return the predicted box in its frame."""
        if prev_T_cur is not None:
            self.world_T_cur = self.world_T_cur @ prev_T_cur
        predicted = self.world_box.copy()
        predicted[:2] += self.velocity[:2]
        predicted[YAW] = wrap(predicted[YAW] + self.velocity[2])
        return transform_boxes(np.linalg.inv(self.world_T_cur), predicted)

    def travel(self) -> tuple[float, float]:
        """(metres a frame, heading in the current sensor's frame) of the target's motion."""
        speed = float(np.hypot(*self.velocity[:2]))
        heading_world = float(np.arctan2(self.velocity[1], self.velocity[0]))
        sensor_yaw = float(np.arctan2(self.world_T_cur[1, 0], self.world_T_cur[0, 0]))
        return speed, float(wrap(heading_world - sensor_yaw))

    def update(self, box: np.ndarray, *, learn: bool = True) -> None:
        """The target's box in the current frame; ``learn``: let its motion enter the
        velocity (a frame the tracker trusts)."""
        world = transform_boxes(self.world_T_cur, box)
        if learn:
            step = world[:2] - self.world_box[:2]
            step *= min(1.0, MAX_STEP_M / max(float(np.linalg.norm(step)), 1e-9))
            turn = np.clip(wrap(world[YAW] - self.world_box[YAW]), -MAX_TURN_RAD, MAX_TURN_RAD)
            motion = np.array([*step, turn])
            self.velocity = (1 - VELOCITY_GAIN) * self.velocity + VELOCITY_GAIN * motion
            self.trusted_box, self.unsure_frames = world, 0
        else:
            self.unsure_frames += 1
        self.world_box = world

    def relocate(self, box: np.ndarray) -> None:
        """A reset's box for the current frame. Right after trusted frames its jump is a
        correction, not a motion; after two or more frames the tracker was unsure of, the
        way from the last trusted box is the target's motion over them (a car lost while
        the sensor drove past it comes back moving as it does)."""
        world = transform_boxes(self.world_T_cur, box)
        if self.unsure_frames >= 2:
            step = (world[:2] - self.trusted_box[:2]) / self.unsure_frames
            step *= min(1.0, MAX_STEP_M / max(float(np.linalg.norm(step)), 1e-9))
            self.velocity = np.array([*step, 0.0])
        self.trusted_box, self.unsure_frames = world, 0
        self.world_box = world


def crop(points: np.ndarray, box: np.ndarray, margin_m: float, floor_m: float = 0.2) -> np.ndarray:
    """(M, 3) the points within ``box`` grown by ``margin_m`` across and along it (and
    0.3 m above), above its bottom by ``floor_m`` (the road under it), in the box's frame."""
    box = np.asarray(box, dtype=np.float64)
    reach = np.hypot(box[3], box[4]) / 2 + margin_m
    near = (np.abs(points[:, 0] - box[0]) <= reach) & (np.abs(points[:, 1] - box[1]) <= reach)
    local = to_box_frame(points[near], box)
    half = box[3:6] / 2
    keep = (
        (np.abs(local[:, 0]) <= half[0] + margin_m)
        & (np.abs(local[:, 1]) <= half[1] + margin_m)
        & (local[:, 2] >= -half[2] + floor_m)
        & (local[:, 2] <= half[2] + 0.3)
    )
    return local[keep]


class PointModel:
    """The target's points in its box frame (voxel means): the first frame's and those of
    the last ``RECENT_FRAMES`` frames added — old frames leave, so a small error of one
    frame cannot build up in the model. Each frame is reduced to its voxels once, as it is
    added."""

    def __init__(self, first: np.ndarray) -> None:
        self.first = _Voxels.of(first)
        self.recent: deque[_Voxels] = deque(maxlen=RECENT_FRAMES)
        self.points = self.first.means()
        self._tree = None

    def add(self, local: np.ndarray) -> None:
        if not len(local):
            return
        self.recent.append(_Voxels.of(local))
        merged = _Voxels.merge([self.first, *self.recent]).means()
        if len(merged) > MODEL_POINTS:
            merged = merged[
                np.random.default_rng(len(merged)).choice(len(merged), MODEL_POINTS, replace=False)
            ]
        self.points = merged
        self._tree = None

    @property
    def tree(self):  # noqa: ANN201 - a scipy cKDTree
        from scipy.spatial import cKDTree

        if self._tree is None:
            self._tree = cKDTree(self.points if len(self.points) else np.zeros((1, 3)))
        return self._tree


VOXEL_SPAN = 1 << 20
"""Voxel indices are offset into 0 … VOXEL_SPAN along each axis (±52 km of 10 cm voxels)."""


@dataclass(frozen=True)
class _Voxels:
    """Points summed per ``VOXEL_M`` voxel: the voxels' keys (V,), sums (V, 3) and counts (V,)."""

    keys: np.ndarray
    sums: np.ndarray
    counts: np.ndarray

    @classmethod
    def of(cls, points: np.ndarray) -> _Voxels:
        cells = np.floor(np.asarray(points, dtype=np.float64)[:, :3] / VOXEL_M).astype(np.int64)
        cells += VOXEL_SPAN // 2
        keys = (cells[:, 0] * VOXEL_SPAN + cells[:, 1]) * VOXEL_SPAN + cells[:, 2]
        return cls._summed(keys, np.asarray(points, dtype=np.float64)[:, :3], np.ones(len(keys)))

    @classmethod
    def merge(cls, parts: list[_Voxels]) -> _Voxels:
        return cls._summed(
            np.concatenate([p.keys for p in parts]),
            np.concatenate([p.sums for p in parts]),
            np.concatenate([p.counts for p in parts]),
        )

    @classmethod
    def _summed(cls, keys: np.ndarray, sums: np.ndarray, counts: np.ndarray) -> _Voxels:
        unique, inverse = np.unique(keys, return_inverse=True)
        total = np.column_stack(
            [np.bincount(inverse, sums[:, k], minlength=len(unique)) for k in range(3)]
        )
        return cls(unique, total.reshape(-1, 3), np.bincount(inverse, counts, len(unique)))

    def means(self) -> np.ndarray:
        return self.sums / np.maximum(self.counts, 1)[:, None]


IN_BOX_MARGIN_M = 0.05
"""``in_box`` takes the returns this close outside a box as its own (its surface's noise)."""


def in_box(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(M, 3) the points inside ``box`` (above the road under it), in the box's frame."""
    local = crop(points, box, IN_BOX_MARGIN_M, floor_m=0.2)
    return local[local[:, 2] <= box[H] / 2 + IN_BOX_MARGIN_M]


def nearby(points: np.ndarray, box: np.ndarray, reach_m: float) -> np.ndarray:
    """The points (N, ≥3) within ``reach_m`` + the box's half diagonal of its centre along x
    and y: what every later step of a frame looks at, cut from the scan once (``crop`` and
    ``in_box`` of a box within ``reach_m`` − their margin of it answer the same on them as
    on the whole scan)."""
    reach = reach_m + np.hypot(box[L], box[W]) / 2
    return points[
        (np.abs(points[:, 0] - box[0]) <= reach) & (np.abs(points[:, 1] - box[1]) <= reach)
    ]
