"""Which detection is the target, and how a reset joins it with the tracker's box.

**Association.** A detection's quality is its detector score × how alike its footprint is
to the target's. Among the detections within the gate of the tracker's box whose quality
reaches ``ACCEPT``, and whose points the target's shape explains (at least ``EXPLAINED`` of
the returns in it lie near the tracker's point model, once it has one: a detection the
tracked shape does not explain is another object, however near), the one with the best
quality × a Gaussian of its distance from the tracker's box (σ = ``SIGMA_M``) is the target.
The gate narrows as the tracker grows sure of itself — from ``GATE_M`` at confidence 0 to
``SURE_GATE_M`` at 1 — so a detector run on a frame the tracker was sure of only corrects
its box, and cannot hand the target over to a neighbouring car.

**Fusion.** A reset does not throw the tracker's box away: each of the two is a
measurement with its own uncertainty — the detection's centre ``DETECTOR_SIGMA_M`` / its
quality; the tracker's its own ``sigma_m`` (how well it places a box it is sure of) / its
confidence, or, when it has been unsure for only a few frames, its prediction's: that
growing by ``DRIFT_M`` a frame since the last box it trusted (a target it cannot see for a
moment is still where the motion model puts it) — and the reset box is their
inverse-variance mean: the centre, the bottom, the heading (the detection's or its
reverse, whichever is nearer the tracker's: a box's front and back look alike) and the
size, for which the target's given size counts as a measurement of ``SIZE_SIGMA_M``. A
tracker that is sure keeps nearly its own box; a lost one takes nearly the detection's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from services.lib.boxes import YAW, H, L, W, Z, wrap
from services.tracking.detections import Detections

GATE_M = 3.0
SURE_GATE_M = 1.0
SIGMA_M = 1.2
ACCEPT = 0.2
EXPLAINED = 0.35
"""The least share of a detection's returns the target's point model must explain."""
WINDOW_M = 12.0
"""Half the side of the bird's-eye window around the target the detector searches."""
DETECTOR_SIGMA_M = 0.3
"""A sure detection's centre error (m)."""
DRIFT_M = 0.15
"""How far a prediction strays a frame (m) from the last box the tracker trusted."""
SIZE_SIGMA_M = 0.1
"""The target's size, given in its first frame, as a measurement."""
DETECTOR_SIZE_SIGMA_M = 0.3
LEAST_WEIGHT = 0.05
"""Confidences and qualities are floored here (a weight of zero would divide by zero)."""


@dataclass(frozen=True)
class Association:
    index: int | None
    """The chosen detection (None: none is the target)."""
    score: float
    """Its quality (0 when none is the target)."""


def search_window(box: np.ndarray) -> np.ndarray:
    """(x0, y0, x1, y1): the window around ``box`` the detector looks in."""
    return np.array([box[0] - WINDOW_M, box[1] - WINDOW_M, box[0] + WINDOW_M, box[1] + WINDOW_M])


def reset_box(detection: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The target's box placed on a detection: its size, the detection's centre and bottom,
    the detection's heading or its reverse, whichever is nearer the target's."""
    out = np.asarray(target, dtype=np.float64).copy()
    out[:2] = detection[:2]
    out[Z] = detection[Z] - detection[H] / 2 + target[H] / 2
    out[YAW] = _towards(detection[YAW], target[YAW])
    return out


def _towards(heading: float, reference: float) -> float:
    """``heading`` or its reverse, whichever is nearer ``reference``."""
    flip = abs(wrap(heading - reference)) > np.pi / 2
    return float(wrap(heading + (np.pi if flip else 0.0)))


def fuse(
    tracked: np.ndarray,
    confidence: float,
    detection: np.ndarray,
    quality: float,
    unsure_frames: int = 0,
    sigma_m: float = 0.15,
) -> np.ndarray:
    """The reset box (see the module's note): the tracker's box (given size) at its
    confidence (0–1), unsure of it for ``unsure_frames`` in a row, placed to ``sigma_m``
    when sure, and a detection at its quality (0–1)."""
    tracked = np.asarray(tracked, dtype=np.float64)
    tracker_sigma = min(
        sigma_m / max(confidence, LEAST_WEIGHT),
        float(np.hypot(sigma_m, DRIFT_M * unsure_frames)),
    )
    tracker_weight = tracker_sigma**-2
    detector_weight = (max(quality, LEAST_WEIGHT) / DETECTOR_SIGMA_M) ** 2
    share = detector_weight / (tracker_weight + detector_weight)
    size_share = (max(quality, LEAST_WEIGHT) / DETECTOR_SIZE_SIGMA_M) ** 2
    size_share /= size_share + SIZE_SIGMA_M**-2
    out = tracked.copy()
    out[L:YAW] = tracked[L:YAW] + size_share * (detection[L:YAW] - tracked[L:YAW])
    out[:2] = tracked[:2] + share * (detection[:2] - tracked[:2])
    bottom = tracked[Z] - tracked[H] / 2
    bottom += share * (detection[Z] - detection[H] / 2 - bottom)
    out[Z] = bottom + out[H] / 2
    turn = wrap(_towards(detection[YAW], tracked[YAW]) - tracked[YAW])
    out[YAW] = wrap(tracked[YAW] + share * turn)
    return out


def associate(
    detections: Detections,
    tracked: np.ndarray,
    appearance: Callable[[np.ndarray], float] | None = None,
    confidence: float = 0.0,
) -> Association:
    """Pick the target among ``detections`` given the tracker's box ``tracked`` (whose size
    is the target's), how sure the tracker is of it (0–1), and ``appearance``: the share of
    a box's returns the target's shape explains (None when the tracker keeps no shape)."""
    if not len(detections):
        return Association(None, 0.0)
    distance = np.linalg.norm(detections.boxes[:, :2] - tracked[:2], axis=1)
    footprint = detections.boxes[:, L] * detections.boxes[:, W] / (tracked[L] * tracked[W])
    quality = detections.scores * np.exp(-np.abs(np.log(footprint)))
    gate = GATE_M + (SURE_GATE_M - GATE_M) * float(np.clip(confidence, 0.0, 1.0))
    candidates = np.flatnonzero((distance <= gate) & (quality >= ACCEPT))
    if appearance is not None and len(candidates):
        explained = np.array(
            [appearance(reset_box(detections.boxes[i], tracked)) for i in candidates]
        )
        candidates = candidates[explained >= EXPLAINED]
    if not len(candidates):
        return Association(None, 0.0)
    ranking = quality[candidates] * np.exp(-0.5 * (distance[candidates] / SIGMA_M) ** 2)
    best = int(candidates[ranking.argmax()])
    return Association(best, float(quality[best]))
