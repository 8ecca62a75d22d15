"""A fast tracker without learning: the target's point model registered to each scan.

Each frame the motion model predicts the box; the scan's points around it (above the road)
are matched to the target's point model by a trimmed point-to-point ICP in the ground
plane (x, y, heading): each scan point to its nearest model point, the trim closing from
0.6 m to 0.25 m. The box moves by the registration, its heading turned at most 0.1 rad a
frame and drawn towards the direction of travel when the target moves; its height follows
the road under it; its size stays the given one.

The confidence multiplies what would go wrong when the tracker drifts: the share of the
box's points the model explains (within 0.2 m), whether there are enough of them, and
whether the registration agrees with the motion model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.lib.boxes import YAW, H, L, Z, from_box_frame, inside, wrap
from services.tracking.correlation import best_shift
from services.tracking.tracker import MotionModel, PointModel, TrackStep, crop, in_box, nearby


@dataclass(frozen=True)
class GeometricConfig:
    margin_m: float = 1.2
    """How far around the predicted box the scan is searched."""
    iterations: int = 12
    trim_m: tuple[float, float] = (0.6, 0.25)
    explained_m: float = 0.2
    enough_points: int = 25
    motion_scale_m: float = 1.0
    """A registration this far from the prediction halves the confidence's motion term."""
    learn_above: float = 0.45
    """Frames with at least this confidence add their points to the model and their
    motion to the velocity."""
    search_m: float = 3.6
    """How far a wide search looks: on the first frames (the target's velocity is unknown)
    and after a frame the tracker did not trust."""
    cell_m: float = 0.2
    max_turn_rad: float = 0.1
    """The most the registration may turn the box in a frame."""
    moving_m: float = 0.15
    """Above this much motion a frame (1.5 m/s) a car heads where it goes."""
    height_gain: float = 0.3
    """The share of the road's height change under the target taken each frame."""
    registered_points: int = 800
    """At most this many of the scan's points (a random, fixed choice) are registered and
    scored: a car a few metres away returns 20 000, and a few hundred place it as well
    (the simulated bench's Success was the same with 1 500 and with all of them)."""


def thinned(points: np.ndarray, most: int) -> np.ndarray:
    """At most ``most`` of ``points``: a fixed random choice (the same scan gives the same)."""
    if len(points) <= most:
        return points
    return points[np.random.default_rng(len(points)).choice(len(points), most, replace=False)]


def coarse_offset(
    scan_local: np.ndarray, model: PointModel, radius_m: float, cell_m: float
) -> np.ndarray:
    """(dx, dy) within ``radius_m`` where the model's bird's-eye occupancy best overlaps
    the scan's (both in the predicted box's frame)."""
    return best_shift(scan_local[:, :2], model.points[:, :2], radius_m, cell_m)


def road_offset(points: np.ndarray, box: np.ndarray) -> float:
    """How far the road around a box lies above its bottom (metres; 0 when too few returns
    say): the low tenth of the returns within a metre of its footprint and a metre of its
    bottom. The road, not the registration, sets a box's height — a partial view's points
    would pull it up or down."""
    grown = box.copy()
    grown[L:H] += 2.0
    grown[Z] = box[Z] - box[H] / 2
    grown[H] = 2.0
    near = points[inside(points, grown), 2]
    if len(near) < 10:
        return 0.0
    return float(np.percentile(near, 10) - (box[Z] - box[H] / 2))


def register(
    scan_local: np.ndarray,
    model: PointModel,
    config: GeometricConfig,
    start: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """(dx, dy, dz, dθ) moving the predicted box onto the target, from the scan's points in
    the predicted box's frame (starting at ``start``); and how many points matched at the
    end. (dz is the matches' mean height difference; the tracker takes its height from the
    road instead.)"""
    pose = np.zeros(4) if start is None else start.astype(np.float64).copy()
    matched = 0
    trims = np.geomspace(config.trim_m[0], config.trim_m[1], config.iterations)
    for trim in trims:
        c, s = np.cos(pose[3]), np.sin(pose[3])
        # scan points into the current estimate's box frame
        shifted = scan_local - pose[:3]
        canonical = np.column_stack(
            [
                c * shifted[:, 0] + s * shifted[:, 1],
                -s * shifted[:, 0] + c * shifted[:, 1],
                shifted[:, 2],
            ]
        )
        distance, nearest = model.tree.query(canonical, distance_upper_bound=trim)
        good = np.isfinite(distance)
        matched = int(good.sum())
        if matched < 5:
            break
        target = model.points[nearest[good]]  # in the box frame
        source = scan_local[good]  # in the predicted box's frame
        # the rigid motion (θ, t) with source ≈ R(θ) target + t, in the ground plane
        target_mean, source_mean = target.mean(axis=0), source.mean(axis=0)
        a, b = target[:, :2] - target_mean[:2], source[:, :2] - source_mean[:2]
        theta = np.arctan2((a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum(), (a * b).sum())
        c, s = np.cos(theta), np.sin(theta)
        rotated = np.array(
            [c * target_mean[0] - s * target_mean[1], s * target_mean[0] + c * target_mean[1]]
        )
        new = np.array([*(source_mean[:2] - rotated), source_mean[2] - target_mean[2], theta])
        change = np.abs(new - pose)
        pose = new
        if change[:3].max() < 0.002 and change[3] < 0.0005:
            break
    return pose, matched


class GeometricTracker:
    name = "geometric"
    sigma_m = 0.15
    """A registration a sure frame places to a few centimetres; the model's own partial
    view keeps it from better."""

    def __init__(self, config: GeometricConfig | None = None) -> None:
        self.config = config or GeometricConfig()

    def start(self, points: np.ndarray, box: np.ndarray) -> None:
        self.box = np.asarray(box, dtype=np.float64).copy()
        self.motion = MotionModel(self.box)
        self.model = PointModel(in_box(points, self.box))
        self.searching = 2  # frames of wide search left: the target's velocity is unknown

    def step(self, points: np.ndarray, prev_T_cur: np.ndarray | None) -> TrackStep:
        config = self.config
        predicted = self.motion.advance(prev_T_cur)
        wide = self.searching > 0
        radius = config.search_m + config.margin_m if wide else config.margin_m
        points = nearby(points, predicted, radius + 2.5)
        scan_local = crop(points, predicted, radius)
        box, confidence, count = predicted.copy(), 0.0, 0
        if len(scan_local) >= 5 and len(self.model.points) >= 5:
            start = np.zeros(4)
            if wide:
                start[:2] = coarse_offset(scan_local, self.model, config.search_m, config.cell_m)
            pose, _ = register(
                thinned(scan_local, config.registered_points), self.model, config, start
            )
            pose[2] = 0.0
            box = predicted.copy()
            box[:3] = from_box_frame(pose[None, :3], predicted)[0]
            box[YAW] = self._heading(predicted[YAW], pose[3])
            box[Z] += config.height_gain * road_offset(points, box)
            target = in_box(points, box)
            count = len(target)
            confidence = self._confidence(target, np.linalg.norm(pose[:2]) if not wide else 0.0)
            if confidence >= config.learn_above:
                self.model.add(target)
        trusted = confidence >= config.learn_above
        self.motion.update(box, learn=trusted)
        self.searching = self.searching - 1 if trusted else 1
        self.box = box
        return TrackStep(box, confidence, count, predicted)

    def _heading(self, predicted_rad: float, turn_rad: float) -> float:
        """The registration's heading, turned at most ``max_turn_rad``, drawn towards the
        direction of travel as the target moves faster (a car does not slide sideways)."""
        config = self.config
        registered = predicted_rad + np.clip(turn_rad, -config.max_turn_rad, config.max_turn_rad)
        speed, travel = self.motion.travel()
        if speed <= config.moving_m:
            return float(wrap(predicted_rad + 0.5 * (registered - predicted_rad)))
        if abs(wrap(travel - registered)) > np.pi / 2:  # reversing, or the box's back is its front
            travel += np.pi
        weight = min(0.7, (speed - config.moving_m) / 0.5)
        return float(wrap(registered + weight * wrap(travel - registered)))

    def _confidence(self, target: np.ndarray, moved_m: float) -> float:
        config = self.config
        if not len(target):
            return 0.0
        distance, _ = self.model.tree.query(
            thinned(target, config.registered_points), distance_upper_bound=config.explained_m
        )
        explained = float(np.isfinite(distance).mean())
        enough = min(1.0, len(target) / config.enough_points)
        agrees = float(np.exp(-np.log(2) * (moved_m / config.motion_scale_m) ** 2))
        return explained * np.sqrt(enough) * np.sqrt(agrees)

    def reset(self, points: np.ndarray, box: np.ndarray) -> np.ndarray:
        """A reset's box is where registration starts, not where the target is: the target's
        model registered from it (the ICP of ``step``, without the motion model) moves it
        onto the target when the registered box explains the returns well enough to learn
        from, and only then do those returns join the model — a detection's few
        centimetres of error would otherwise be learnt into the target's shape. A target
        the tracker has no shape of yet takes its first from the reset box."""
        config = self.config
        box = np.asarray(box, dtype=np.float64).copy()
        if len(self.model.points) >= 5:
            near = nearby(points, box, config.margin_m + 2.5)
            scan_local = crop(near, box, config.margin_m)
            if len(scan_local) >= 5:
                pose, _ = register(
                    thinned(scan_local, config.registered_points), self.model, config
                )
                refined = box.copy()
                refined[:2] = from_box_frame(np.array([[pose[0], pose[1], 0.0]]), box)[0, :2]
                refined[YAW] = wrap(
                    box[YAW] + np.clip(pose[3], -config.max_turn_rad, config.max_turn_rad)
                )
                target = in_box(near, refined)
                if self._confidence(target, 0.0) >= config.learn_above:
                    box = refined
                    self.model.add(target)
        else:
            self.model.add(in_box(points, box))
        self.box = box
        self.motion.relocate(box)
        self.searching = 0
        return box

    def appearance(self, points: np.ndarray, box: np.ndarray) -> float:
        if len(self.model.points) < self.config.enough_points:
            return 1.0  # too little of the target seen yet to tell it from another car
        target = in_box(points, box)
        if len(target) < 3:
            return 0.0
        distance, _ = self.model.tree.query(
            thinned(target, self.config.registered_points), distance_upper_bound=0.3
        )
        return float(np.isfinite(distance).mean())
