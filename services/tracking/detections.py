"""What a car detector answers: boxes in the LiDAR frame with a score each."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Detections:
    boxes: np.ndarray
    """(D, 7) LiDAR boxes ``x y z l w h yaw`` (metres, radians)."""
    scores: np.ndarray
    """(D,) 0–1."""
    points: np.ndarray
    """(D,) points in each detection's cluster."""

    def __len__(self) -> int:
        return len(self.scores)

    def select(self, mask: np.ndarray) -> Detections:
        return Detections(self.boxes[mask], self.scores[mask], self.points[mask])


def empty_detections() -> Detections:
    return Detections(np.zeros((0, 7)), np.zeros(0), np.zeros(0, dtype=np.int64))
