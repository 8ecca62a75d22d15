"""How well a car detector does on labelled scans, by KITTI's rules where they apply.

A detection is a true positive when its bird's-eye-view IoU with an unmatched labelled car
is at least 0.5 (detections taken by score, greedily). Detections that overlap a van or a
truck (KITTI's neighbouring classes) that much, or whose centre falls in a labelled
DontCare region of the image, count neither way. Recall is over the cars within
``near_m`` of the sensor (bird's-eye distance); precision over the detections in the
camera's field of view (where KITTI labels anything). Each comes with its 95 % Wilson
interval: on a handful of cars a ratio says little, and the interval says how little.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from services.lib import kitti
from services.lib.boxes import bev_iou
from services.tracking.detections import Detections

IOU_MATCH = 0.5
TRUSTED_WIDTH = 0.3
"""A ratio whose 95 % interval is wider than this is marked low-confidence."""
NEIGHBOURS = ("Van", "Truck")


@dataclass(frozen=True)
class ScanTally:
    cars_near: int
    found_near: int
    detections_in_view: int
    true_positives: int
    false_positives: int
    ignored: int


@dataclass(frozen=True)
class DetectionScores:
    scans: int
    cars_near: int
    found_near: int
    recall_near: float | None
    detections_in_view: int
    true_positives: int
    false_positives: int
    precision_in_view: float | None
    near_m: float
    score_threshold: float
    recall_interval: tuple[float, float] | None
    precision_interval: tuple[float, float] | None

    def document(self) -> dict:
        return asdict(self)

    def describe(self) -> str:
        """ "recall within 40 m 3/4 = 0.75 (95 % 0.30–0.95), precision in view …"."""
        judged = self.true_positives + self.false_positives
        return (
            f"recall within {self.near_m:.0f} m {ratio_text(self.found_near, self.cars_near)}, "
            f"precision in view {ratio_text(self.true_positives, judged)}"
        )


def ratio_text(hits: int, total: int) -> str:
    """hits/total with its 95 % interval, marked low-confidence when the interval is too
    wide to trust, or unmeasured when there is nothing to count."""
    interval = wilson_interval(hits, total)
    if interval is None:
        return "unmeasured (nothing to count)"
    low, high = interval
    warning = ", low confidence: too few to measure" if high - low > TRUSTED_WIDTH else ""
    return f"{hits}/{total} = {hits / total:.2f} (95 % {low:.2f}–{high:.2f}{warning})"


def wilson_interval(hits: int, total: int, z: float = 1.96) -> tuple[float, float] | None:
    """The 95 % Wilson score interval of the ratio hits/total (None when total is 0)."""
    if total == 0:
        return None
    ratio = hits / total
    centre = (ratio + z * z / (2 * total)) / (1 + z * z / total)
    half = (
        z * np.sqrt(ratio * (1 - ratio) / total + z * z / (4 * total * total)) / (1 + z * z / total)
    )
    return round(float(centre - half), 3), round(float(centre + half), 3)


def in_view(boxes: np.ndarray, calibration: kitti.Calibration, size: tuple[int, int]) -> np.ndarray:
    """(N,) bool: the boxes' centres project into the image and lie ahead of the camera."""
    pixels, depth = calibration.velo_to_image(np.asarray(boxes)[:, :3])
    width, height = size
    return (
        (depth > 0.5)
        & (pixels[:, 0] >= 0)
        & (pixels[:, 0] < width)
        & (pixels[:, 1] >= 0)
        & (pixels[:, 1] < height)
    )


@dataclass(frozen=True)
class ScanMatch:
    """One scan's detections against its labels, detection by detection."""

    in_view: np.ndarray
    """(D,) bool: the detection lies in the camera's view (where precision is judged)."""
    true_positive: np.ndarray
    """(D,) bool: it matches a labelled car."""
    ignored: np.ndarray
    """(D,) bool: it overlaps a van or truck, or a DontCare region: counted neither way."""
    cars: np.ndarray
    """(C, 7) the labelled cars' LiDAR boxes."""
    found: np.ndarray
    """(C,) bool: a detection matched the car."""
    near: np.ndarray
    """(C,) bool: the car is within ``near_m`` (where recall is judged)."""

    def tally(self) -> ScanTally:
        view, hit = self.in_view, self.true_positive
        return ScanTally(
            cars_near=int(self.near.sum()),
            found_near=int((self.near & self.found).sum()),
            detections_in_view=int(view.sum()),
            true_positives=int((view & hit).sum()),
            false_positives=int((view & ~hit & ~self.ignored).sum()),
            ignored=int((view & self.ignored).sum()),
        )


def match_scan(
    detections: Detections,
    labels: kitti.Labels,
    calibration: kitti.Calibration,
    *,
    near_m: float = 40.0,
    image_size: tuple[int, int] = (1242, 375),
) -> ScanMatch:
    """Match one scan's detections (already thresholded) to its labelled cars, by score."""
    cars = kitti.camera_to_lidar(labels.of_type("Car").camera_box, calibration)
    neighbours = kitti.camera_to_lidar(labels.of_type(*NEIGHBOURS).camera_box, calibration)
    dont_care = labels.of_type(kitti.DONT_CARE).bbox
    view = (
        in_view(detections.boxes, calibration, image_size) if len(detections) else np.zeros(0, bool)
    )
    matched = np.zeros(len(cars), dtype=bool)
    true_positive = np.zeros(len(detections), dtype=bool)
    for index in np.argsort(-detections.scores):
        if not len(cars):
            break
        overlap = np.where(matched, 0.0, bev_iou(cars, detections.boxes[index][None]))
        best = int(overlap.argmax())
        if overlap[best] >= IOU_MATCH:
            matched[best] = True
            true_positive[index] = True
    ignored = np.zeros(len(detections), dtype=bool)
    if len(neighbours) and len(detections):
        ignored |= (bev_iou(detections.boxes[:, None], neighbours[None]) >= IOU_MATCH).any(axis=1)
    if len(dont_care) and len(detections):
        pixels, _ = calibration.velo_to_image(detections.boxes[:, :3])
        inside = (
            (pixels[:, None, 0] >= dont_care[None, :, 0]) & (pixels[:, None, 0] <= dont_care[None, :, 2])
            & (pixels[:, None, 1] >= dont_care[None, :, 1]) & (pixels[:, None, 1] <= dont_care[None, :, 3])
        )  # fmt: skip
        ignored |= inside.any(axis=1)
    ignored &= ~true_positive
    near = np.hypot(cars[:, 0], cars[:, 1]) <= near_m if len(cars) else np.zeros(0, bool)
    return ScanMatch(view, true_positive, ignored, cars.reshape(-1, 7), matched, near)


def combine(tallies: list[ScanTally], near_m: float, score_threshold: float) -> DetectionScores:
    total = {key: sum(getattr(t, key) for t in tallies) for key in ScanTally.__dataclass_fields__}
    judged = total["true_positives"] + total["false_positives"]
    return DetectionScores(
        scans=len(tallies),
        cars_near=total["cars_near"],
        found_near=total["found_near"],
        recall_near=total["found_near"] / total["cars_near"] if total["cars_near"] else None,
        detections_in_view=total["detections_in_view"],
        true_positives=total["true_positives"],
        false_positives=total["false_positives"],
        precision_in_view=total["true_positives"] / judged if judged else None,
        near_m=near_m,
        score_threshold=score_threshold,
        recall_interval=wilson_interval(total["found_near"], total["cars_near"]),
        precision_interval=wilson_interval(total["true_positives"], judged),
    )
