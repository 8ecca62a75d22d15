"""One-Pass Evaluation as the single-object tracking literature computes it (SC3D, P2B and
their successors; the thesis's Table 5.1).

Each frame of every tracklet gives the 3D IoU of the tracked box with the true one and the
distance between their centres (the first frame, given, included). Pooled over the frames
of all tracklets of a split:

- Success = the area under the curve of the share of frames whose IoU is at least t, for 21
  thresholds t evenly over 0–1, in percent;
- Precision = the area under the curve of the share of frames whose centre error is at most
  e, for 21 thresholds e evenly over 0–2 m, in percent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.lib.boxes import centre_distance, iou_3d

SUCCESS_THRESHOLDS = np.linspace(0.0, 1.0, 21)
PRECISION_THRESHOLDS_M = np.linspace(0.0, 2.0, 21)


def success_curve(overlaps: np.ndarray) -> np.ndarray:
    """(21,) the share of frames with IoU ≥ each threshold."""
    overlaps = np.asarray(overlaps, dtype=np.float64)
    return (overlaps[None, :] >= SUCCESS_THRESHOLDS[:, None]).mean(axis=1)


def precision_curve(errors_m: np.ndarray) -> np.ndarray:
    """(21,) the share of frames with centre error ≤ each threshold (metres)."""
    errors_m = np.asarray(errors_m, dtype=np.float64)
    return (errors_m[None, :] <= PRECISION_THRESHOLDS_M[:, None]).mean(axis=1)


def area_under(curve: np.ndarray, thresholds: np.ndarray) -> float:
    """The trapezoidal area under ``curve`` over ``thresholds``, as a percentage of the
    thresholds' span."""
    heights = (curve[1:] + curve[:-1]) / 2
    return float((heights * np.diff(thresholds)).sum() / (thresholds[-1] - thresholds[0]) * 100)


@dataclass(frozen=True)
class OPEResult:
    success: float
    precision: float
    frames: int
    tracklets: int
    success_curve: np.ndarray
    precision_curve: np.ndarray
    mean_iou: float
    mean_error_m: float

    def document(self) -> dict:
        return {
            "success": round(self.success, 3),
            "precision": round(self.precision, 3),
            "frames": self.frames,
            "tracklets": self.tracklets,
            "mean_iou": round(self.mean_iou, 4),
            "mean_centre_error_m": round(self.mean_error_m, 4),
            "success_curve": {
                "iou_thresholds": SUCCESS_THRESHOLDS.round(3).tolist(),
                "share": self.success_curve.round(5).tolist(),
            },
            "precision_curve": {
                "error_thresholds_m": PRECISION_THRESHOLDS_M.round(3).tolist(),
                "share": self.precision_curve.round(5).tolist(),
            },
        }


def frame_scores(tracked: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the 3D IoU and the centre error (metres) of (F, 7) tracked boxes against
    (F, 7) true ones."""
    return iou_3d(tracked, truth), centre_distance(tracked, truth)


def one_pass(overlaps: list[np.ndarray], errors_m: list[np.ndarray]) -> OPEResult:
    """Success and Precision pooled over tracklets' per-frame IoUs and centre errors."""
    if not overlaps or not sum(len(o) for o in overlaps):
        raise ValueError("no frames to evaluate")
    iou = np.concatenate(overlaps)
    error = np.concatenate(errors_m)
    successes, precisions = success_curve(iou), precision_curve(error)
    return OPEResult(
        success=area_under(successes, SUCCESS_THRESHOLDS),
        precision=area_under(precisions, PRECISION_THRESHOLDS_M),
        frames=len(iou),
        tracklets=len(overlaps),
        success_curve=successes,
        precision_curve=precisions,
        mean_iou=float(iou.mean()),
        mean_error_m=float(error.mean()),
    )
