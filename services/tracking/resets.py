"""When the detector re-initialises the tracker.

- ``never``: the tracker alone (Table 5.1's "only tracking").
- ``every:N``: the thesis's fixed frequency 1/N — the detector's branch runs on every N-th
  frame after the first and its box is fused into the tracker's (the tracker still steps
  on those frames: its box anchors the detector's search window and stands when no
  detection is the target).
- ``adaptive[:BUDGET]``: the thesis's future work, detect only when needed. The tracker
  runs every frame; the detector runs as well when the tracker is unsure of its answer
  (low confidence, a sudden loss of the target's points, a registration far from the
  motion model's prediction) and the budget allows. The budget (default 10 %) accrues by
  that share of a detection every frame, holds at most ``CAPACITY`` detections, and a
  detection spends one: over a tracklet the detector runs on at most BUDGET of its frames
  (plus the capacity). A budget left idle stays unspent: a detection on a frame the tracker
  was sure of only adds its error (on the simulated bench, spending it as refreshes cost
  the geometric tracker five points of Success), and a target not seen lately — no
  returns in its box, none in the recent frames — gives a detector nothing to correct.
"""

from __future__ import annotations

from dataclasses import dataclass

from services.tracking.tracker import TrackStep

CAPACITY = 2.0
UNSURE_BELOW = 0.55
POINTS_DROP = 0.4
"""A frame whose box holds less than this share of the recent frames' points is unsure."""
STRAY_M = 1.2
"""A registration this far from the motion model's prediction is unsure."""


@dataclass(frozen=True)
class ResetPolicy:
    mode: str
    """``never``, ``every`` or ``adaptive``."""
    period: int = 0
    budget: float = 0.10

    @classmethod
    def parse(cls, text: str) -> ResetPolicy:
        """``never``, ``every:N`` (N ≥ 1) or ``adaptive[:PERCENT]`` (0 < PERCENT ≤ 100)."""
        name, _, value = text.strip().partition(":")
        if name == "never" and not value:
            return cls("never")
        if name == "every":
            try:
                period = int(value)
            except ValueError:
                period = 0
            if period < 1:
                raise ValueError(
                    f"reset {text!r}: every:N needs a whole N ≥ 1 (every:15 resets on every 15th frame)"
                )
            return cls("every", period=period)
        if name == "adaptive":
            try:
                percent = float(value) if value else 10.0
            except ValueError:
                percent = -1.0
            if not 0 < percent <= 100:
                raise ValueError(
                    f"reset {text!r}: adaptive:BUDGET needs a budget in percent, 0 < BUDGET ≤ 100"
                )
            return cls("adaptive", budget=percent / 100)
        raise ValueError(f"reset {text!r}: use never, every:N or adaptive[:BUDGET]")

    def text(self) -> str:
        if self.mode == "every":
            return f"every:{self.period}"
        if self.mode == "adaptive":
            return f"adaptive:{self.budget * 100:g}"
        return "never"


class AdaptiveGate:
    """The adaptive policy's state over one tracklet."""

    def __init__(self, budget: float) -> None:
        self.budget = budget
        self.tokens = 1.0
        self.recent_points: list[int] = []

    def unsure(self, step: TrackStep, moved_m: float) -> bool:
        if step.points == 0 and not any(self.recent_points):
            return False  # nothing of the target seen lately: nothing a detector could correct
        usual = (
            sorted(self.recent_points)[len(self.recent_points) // 2]
            if self.recent_points
            else step.points
        )
        return (
            step.confidence < UNSURE_BELOW
            or (usual >= 10 and step.points < POINTS_DROP * usual)
            or moved_m > STRAY_M
        )

    def decide(self, step: TrackStep, moved_m: float) -> bool:
        """Whether to run the detector on this frame (spending the budget if so)."""
        self.tokens = min(CAPACITY, self.tokens + self.budget)
        want = self.tokens >= 1.0 and self.unsure(step, moved_m)
        self.recent_points = (self.recent_points + [step.points])[-10:]
        if want:
            self.tokens -= 1.0
        return want
