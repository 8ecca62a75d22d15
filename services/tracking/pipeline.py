"""The thesis's system (Figure 5.2): a tracker branch and a detector branch, with the reset
policy choosing when the detector re-initialises the tracker.

On a frame the policy gives to the detector, the detector looks in a window around where
the tracker last had the target (``association.search_window``), the association picks the
target among its cars, and the tracker is reset to the detection fused with its own box by
their confidences (``association.fuse``); when no detection is the target, the tracker's
own answer stands.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import partial
from typing import Protocol

import numpy as np

from contract.vocabulary import Count
from services.lib.boxes import inside
from services.tracking.association import associate, fuse, search_window
from services.tracking.detections import Detections
from services.tracking.resets import UNSURE_BELOW, AdaptiveGate, ResetPolicy
from services.tracking.tracker import Tracker, TrackStep


class Detector(Protocol):
    name: str

    def detect(self, points: np.ndarray, region: np.ndarray | None = None) -> Detections:
        """Cars in a scan (within ``region`` = x0, y0, x1, y1 when given)."""
        ...


@dataclass(frozen=True)
class FrameResult:
    frame: int
    box: np.ndarray
    """(7,) LiDAR frame."""
    confidence: float
    points: int
    detector_ran: bool
    reset: bool
    """The detector's box was fused into the tracker's."""


@dataclass
class TrackResult:
    frames: list[FrameResult] = field(default_factory=list)
    tracker_s: float = 0.0
    detector_s: float = 0.0
    read_s: float = 0.0

    @property
    def boxes(self) -> np.ndarray:
        return np.array([f.box for f in self.frames])

    @property
    def detector_frames(self) -> int:
        return sum(f.detector_ran for f in self.frames)

    @property
    def cost_percent(self) -> float:
        """The thesis's cost: the share of frames the detector ran on, percent."""
        return 100.0 * self.detector_frames / max(len(self.frames), 1)

    @property
    def compute_fps(self) -> float:
        """Frames per second of the tracker and the detector (scans already in memory)."""
        return (len(self.frames) - 1) / max(self.tracker_s + self.detector_s, 1e-9)

    @property
    def fps(self) -> float:
        """Frames per second including reading the scans."""
        return (len(self.frames) - 1) / max(self.tracker_s + self.detector_s + self.read_s, 1e-9)


def track(
    scans: Iterable[tuple[int, np.ndarray, np.ndarray | None]],
    init_box: np.ndarray,
    tracker: Tracker,
    detector: Detector | None,
    policy: ResetPolicy,
    progress: Count | None = None,
    total: int = 0,
) -> TrackResult:
    """Track one target through ``scans`` — (frame, points (N, ≥3), ``prev_T_cur`` ego
    motion or None) in order, the first holding the target's ``init_box``."""
    if policy.mode != "never" and detector is None:
        raise ValueError(f"reset {policy.text()} needs a detector")
    result = TrackResult()
    gate = AdaptiveGate(policy.budget) if policy.mode == "adaptive" else None
    iterator = iter(scans)
    started = time.perf_counter()
    first = next(iterator, None)
    if first is None:
        raise ValueError("no scans to track in")
    frame, points, _ = first
    result.read_s += time.perf_counter() - started
    started = time.perf_counter()
    tracker.start(points, np.asarray(init_box, dtype=np.float64))
    result.tracker_s += time.perf_counter() - started
    given = np.asarray(init_box, dtype=np.float64)
    result.frames.append(
        FrameResult(frame, given, 1.0, int(inside(points, given).sum()), False, False)
    )
    index, unsure_frames = 0, 0
    while True:
        started = time.perf_counter()
        item = next(iterator, None)
        result.read_s += time.perf_counter() - started
        if item is None:
            break
        frame, points, prev_T_cur = item
        index += 1
        scheduled = policy.mode == "every" and index % policy.period == 0
        started = time.perf_counter()
        step: TrackStep = tracker.step(points, prev_T_cur)
        result.tracker_s += time.perf_counter() - started
        box, confidence, ran, reset = step.box, step.confidence, False, False
        unsure_frames = unsure_frames + 1 if step.confidence < UNSURE_BELOW else 0
        if scheduled or (
            gate is not None
            and gate.decide(step, float(np.linalg.norm(step.box[:2] - step.predicted[:2])))
        ):
            started = time.perf_counter()
            detections = detector.detect(points, search_window(step.box))
            chosen = associate(
                detections, step.box, partial(tracker.appearance, points), step.confidence
            )
            if chosen.index is not None:
                box = fuse(
                    step.box,
                    step.confidence,
                    detections.boxes[chosen.index],
                    chosen.score,
                    unsure_frames,
                    tracker.sigma_m,
                )
                box = tracker.reset(points, box)
                confidence, reset, unsure_frames = max(confidence, chosen.score), True, 0
            result.detector_s += time.perf_counter() - started
            ran = True
        result.frames.append(FrameResult(frame, box, float(confidence), step.points, ran, reset))
        if progress:
            progress(index, total)
    return result
