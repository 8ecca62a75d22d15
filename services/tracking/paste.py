"""Ground-truth sampling (SECOND, Yan et al. 2018): labelled cars cut from scans with their
returns and pasted into other scans, so a detector trained on a few real scans sees many
real cars in many real places.

A car moves by a turn about the sensor's vertical axis: its range and the angle the beams
meet it stay, so its ring pattern, its density and the side the sensor sees stay those a
real sensor gives at that place. It is then set on the ground there (a shift of at most
``MAX_LIFT_M``, or the place is refused).

A place is plausible when it is where the labels speak (the caller's ``allowed``: the
camera's view, outside DontCare regions — a background is known to hold no unlabelled car
only there), clear of every labelled object (``CLEARANCE_M`` between footprints) and of the
scan itself (almost no return stands inside the car's box: not in a hedge, a wall or a
parked lorry). Occlusion is respected in a range image of ``AZIMUTH_BIN_DEG`` ×
``ELEVATION_BIN_DEG``: a background return the pasted car hides goes, and so does a car
return something nearer hides; a car left with less than half its returns is not pasted.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from services.lib.boxes import YAW, H, L, Z, bev_iou, inside, wrap
from services.tracking.ground import Ground

MIN_RETURNS = 20
"""A car cut with fewer returns teaches little."""
MAX_LIFT_M = 0.4
CLEARANCE_M = 0.5
STANDING_RETURNS = 5
"""More background returns than this standing in a car's box: the place is not free."""
AZIMUTH_BIN_DEG = 0.2
ELEVATION_BIN_DEG = 0.4
FIELD_DEG = 40.0
"""Cars are placed at azimuths within this of straight ahead (the camera's view)."""


@dataclass(frozen=True)
class CutCar:
    box: np.ndarray
    """(7,) LiDAR box in its own scan."""
    points: np.ndarray
    """(N, 4) its returns above the road (x y z reflectance, metres)."""


def cut_cars(points: np.ndarray, boxes: np.ndarray) -> list[CutCar]:
    """The cars (boxes (K, 7)) of a scan (N, 4) with at least ``MIN_RETURNS`` returns above
    their bottom."""
    out = []
    for box in np.asarray(boxes).reshape(-1, 7):
        mine = points[inside(points, box, margin_m=0.05)]
        mine = mine[mine[:, 2] > box[Z] - box[H] / 2 + 0.1]
        if len(mine) >= MIN_RETURNS:
            out.append(CutCar(box.copy(), mine.copy()))
    return out


def _turned(car: CutCar, angle_rad: float) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    turn = np.array([[c, -s], [s, c]])
    box, points = car.box.copy(), car.points.copy()
    box[:2] = turn @ box[:2]
    box[YAW] = wrap(box[YAW] + angle_rad)
    points[:, :2] = points[:, :2] @ turn.T
    return box, points


def _range_bins(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's range-image bin (N,) and range (N,) in metres."""
    distance = np.linalg.norm(points[:, :3], axis=1)
    azimuth = np.degrees(np.arctan2(points[:, 1], points[:, 0])) + 180.0
    elevation = np.degrees(np.arcsin(np.clip(points[:, 2] / np.maximum(distance, 1e-6), -1, 1)))
    columns = int(360 / AZIMUTH_BIN_DEG)
    row = np.floor((elevation + 90.0) / ELEVATION_BIN_DEG).astype(np.int64)
    column = np.floor(azimuth / AZIMUTH_BIN_DEG).astype(np.int64) % columns
    return row * columns + column, distance


def _occlude(background: np.ndarray, car: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(background kept (N,) bool, car kept (M,) bool): each bin keeps what is nearest."""
    background_bin, background_range = _range_bins(background)
    car_bin, car_range = _range_bins(car)
    bins, inverse = np.unique(car_bin, return_inverse=True)
    car_nearest = np.full(len(bins), np.inf)
    np.minimum.at(car_nearest, inverse, car_range)
    slot = np.searchsorted(bins, background_bin)
    shared = (slot < len(bins)) & (bins[np.minimum(slot, len(bins) - 1)] == background_bin)
    hidden = np.zeros(len(background), dtype=bool)
    hidden[shared] = background_range[shared] > car_nearest[slot[shared]]
    background_nearest = np.full(len(bins), np.inf)
    np.minimum.at(background_nearest, slot[shared], background_range[shared])
    car_hidden = car_range > background_nearest[inverse] + 0.1
    return ~hidden, ~car_hidden


def paste_cars(
    points: np.ndarray,
    occupied: np.ndarray,
    ground: Ground,
    cars: list[CutCar],
    rng: np.random.Generator,
    count: int,
    allowed: Callable[[np.ndarray], np.ndarray],
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``points`` (N, 4) with up to ``count`` of ``cars`` (drawn by ``weights`` when given)
    pasted at plausible places (see the module's note) away from the boxes ``occupied``
    (K, 7: every labelled object); the new scan and the pasted cars' boxes (P, 7).
    ``allowed`` maps box centres (P, 3) to whether the labels speak there."""
    pasted: list[np.ndarray] = []
    taken = np.asarray(occupied, dtype=np.float64).reshape(-1, 7)
    if not cars or count <= 0:
        return points, np.zeros((0, 7))
    for choice in rng.choice(len(cars), size=min(3 * count, 3 * len(cars)), p=weights):
        if len(pasted) == count:
            break
        car = cars[choice]
        azimuth = np.arctan2(car.box[1], car.box[0])
        goal = np.radians(rng.uniform(-FIELD_DEG, FIELD_DEG))
        box, car_points = _turned(car, goal - azimuth)
        floor = box[Z] - box[H] / 2
        lift = -float(ground.height(np.array([[box[0], box[1], 0.0]]))[0]) - floor
        if abs(lift) > MAX_LIFT_M or not allowed(box[None, :3])[0]:
            continue
        box[Z] += lift
        car_points[:, 2] += lift
        grown = taken.copy()
        grown[:, L:H] += 2 * CLEARANCE_M
        if len(grown) and (bev_iou(grown, box[None]) > 0).any():
            continue
        standing = inside(points, box, margin_m=0.2)
        standing[standing] = ground.height(points[standing]) > 0.25
        if standing.sum() > STANDING_RETURNS:
            continue
        keep_background, keep_car = _occlude(points, car_points)
        if keep_car.sum() < 0.5 * len(car_points):
            continue
        points = np.concatenate([points[keep_background], car_points[keep_car]])
        pasted.append(box)
        taken = np.concatenate([taken, box[None]])
    return points, np.array(pasted).reshape(-1, 7)
