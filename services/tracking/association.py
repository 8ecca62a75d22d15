"""Which detection is the target: the one the tracker's box, the detector's confidence, the
target's size and its look agree on best.

A detection's quality is its detector score × how alike its footprint is to the target's ×
(½ + ½ its appearance: how much its points look like the target's model). Among the
detections within the gate of the tracker's box whose quality reaches ``ACCEPT``, the one
with the best quality × a Gaussian of its distance from the tracker's box (σ = ``SIGMA_M``)
is the target. The gate narrows as the tracker
grows sure of itself — from ``GATE_M`` at confidence 0 to ``SURE_GATE_M`` at 1 — so a
detector run on a frame the tracker was sure of only corrects its box, and cannot hand the
target over to a neighbouring car.

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
SURE_GATE_M = 1.0
SIGMA_M = 1.2
ACCEPT = 0.2
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
    confidence: float = 0.0,
) -> Association:
    """Pick the target among ``detections`` given the tracker's box ``tracked`` (whose size
    is the target's) and how sure the tracker is of it (0–1)."""
    if not len(detections):
        return Association(None, 0.0, None)
    distance = np.linalg.norm(detections.boxes[:, :2] - tracked[:2], axis=1)
    footprint = detections.boxes[:, L] * detections.boxes[:, W] / (tracked[L] * tracked[W])
    quality = detections.scores * np.exp(-np.abs(np.log(footprint)))
    gate = GATE_M + (SURE_GATE_M - GATE_M) * float(np.clip(confidence, 0.0, 1.0))
    candidates = np.flatnonzero((distance <= gate) & (quality >= ACCEPT))
    if appearance is not None:
        for index in candidates:
            quality[index] *= 0.5 + 0.5 * appearance(reset_box(detections.boxes[index], tracked))
        candidates = candidates[quality[candidates] >= ACCEPT]
    if not len(candidates):
        return Association(None, 0.0, None)
    ranking = quality[candidates] * np.exp(-0.5 * (distance[candidates] / SIGMA_M) ** 2)
    best = int(candidates[ranking.argmax()])
    return Association(best, float(quality[best]), reset_box(detections.boxes[best], tracked))
