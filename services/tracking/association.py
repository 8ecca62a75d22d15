"""Which detection is the target: the one the tracker's box, the detector's confidence, the
target's size and its look agree on best.

Each detection within ``GATE_M`` of the tracker's box scores its detector score × a
Gaussian of its centre's distance from the tracker's box (σ = ``SIGMA_M``) × how alike its
footprint is to the target's × (½ + ½ its appearance: the share of its points the target's
model explains). The best above ``ACCEPT`` is the target.

The reset box keeps the target's known size (single-object tracking is given it in the
first frame), stands on the detection's bottom, and takes the detection's heading or its
reverse, whichever is nearer the tracker's (a box's front and back look alike).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from services.tracking.boxes import YAW, H, L, W, Z, wrap
from services.tracking.detections import Detections

GATE_M = 3.0
SIGMA_M = 1.2
ACCEPT = 0.08
WINDOW_M = 12.0
"""Half the side of the bird's-eye window around the target the detector searches."""


@dataclass(frozen=True)
class Association:
    index: int | None
    """The chosen detection (None: none is the target)."""
    score: float
    box: np.ndarray | None
    """The reset box (target's size, detection's place and heading)."""


def search_window(box: np.ndarray) -> np.ndarray:
    """(x0, y0, x1, y1): the window around ``box`` the detector looks in."""
    return np.array([box[0] - WINDOW_M, box[1] - WINDOW_M, box[0] + WINDOW_M, box[1] + WINDOW_M])


def reset_box(detection: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The target's box placed on a detection (see the module's note)."""
    out = np.asarray(target, dtype=np.float64).copy()
    out[:2] = detection[:2]
    out[Z] = detection[Z] - detection[H] / 2 + target[H] / 2
    flip = abs(wrap(detection[YAW] - target[YAW])) > np.pi / 2
    out[YAW] = wrap(detection[YAW] + (np.pi if flip else 0.0))
    return out


def associate(
    detections: Detections,
    tracked: np.ndarray,
    appearance: Callable[[np.ndarray], float] | None = None,
) -> Association:
    """Pick the target among ``detections`` given the tracker's box ``tracked`` (whose size
    is the target's)."""
    if not len(detections):
        return Association(None, 0.0, None)
    distance = np.linalg.norm(detections.boxes[:, :2] - tracked[:2], axis=1)
    size = np.exp(
        -np.abs(np.log(detections.boxes[:, L] * detections.boxes[:, W] / (tracked[L] * tracked[W])))
    )
    score = detections.scores * np.exp(-0.5 * (distance / SIGMA_M) ** 2) * size
    score = np.where(distance <= GATE_M, score, 0.0)
    if appearance is not None:
        for index in np.flatnonzero(score > ACCEPT / 2):
            candidate = reset_box(detections.boxes[index], tracked)
            score[index] *= 0.5 + 0.5 * appearance(candidate)
    best = int(score.argmax())
    if score[best] < ACCEPT:
        return Association(None, float(score[best]), None)
    return Association(best, float(score[best]), reset_box(detections.boxes[best], tracked))
