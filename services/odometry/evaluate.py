"""An estimated trajectory against the truth: per-step errors of the relative motions,
the final position error, the absolute trajectory error and the drift.

Poses are matched by time (within half a frame). The per-step error compares each
estimated motion between consecutive matched poses with the true one, in the first pose's
frame; the ATE is the RMS position error after the rigid planar alignment that fits best
(Umeyama without scale), as evo's ``ape`` reports it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from services.odometry import se2
from services.odometry.tum import Trajectory2D


@dataclass(frozen=True)
class OdometryEval:
    poses: int
    distance_m: float
    """Length of the true path."""
    rmse_dx_mm: float
    rmse_dy_mm: float
    rmse_dtheta_deg: float
    final_error_m: float
    ate_rmse_m: float
    drift_percent: float
    """Final position error in % of the distance travelled."""

    def document(self) -> dict:
        return asdict(self)


def match(estimate: Trajectory2D, truth: Trajectory2D) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into estimate, into truth) of the poses at the same time (±half a frame)."""
    if len(truth) < 2:
        raise ValueError("the truth has fewer than 2 poses")
    half_frame = 0.5 * float(np.median(np.diff(truth.t_s)))
    nearest = np.clip(np.searchsorted(truth.t_s, estimate.t_s), 1, len(truth) - 1)
    before = truth.t_s[nearest - 1]
    after = truth.t_s[nearest]
    pick = np.where(estimate.t_s - before < after - estimate.t_s, nearest - 1, nearest)
    close = np.abs(truth.t_s[pick] - estimate.t_s) <= half_frame
    if close.sum() < 2:
        raise ValueError("fewer than 2 estimated poses fall at times of the truth")
    return np.flatnonzero(close), pick[close]


def align_rigid(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The planar rotation + translation (x, y, θ) that moves points ``a`` onto ``b``
    best in the least-squares sense."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    h = (a - ca).T @ (b - cb)
    theta = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = np.cos(theta), np.sin(theta)
    t = cb - np.array([[c, -s], [s, c]]) @ ca
    return np.array([t[0], t[1], theta])


def evaluate(estimate: Trajectory2D, truth: Trajectory2D) -> OdometryEval:
    est_index, true_index = match(estimate, truth)
    est = estimate.pose[est_index]
    true = truth.pose[true_index]
    # both start where the first matched true pose is
    est = se2.compose(se2.compose(true[:1], se2.inverse(est[:1])), est)
    step_error = se2.relative(est) - se2.relative(true)
    step_error[:, 2] = se2.wrap(step_error[:, 2])
    distance_mm = float(np.hypot(*np.diff(truth.pose[:, :2], axis=0).T).sum())
    final_mm = float(np.hypot(*(est[-1, :2] - true[-1, :2])))
    fit = align_rigid(est[:, :2], true[:, :2])
    aligned = se2.compose(fit, est)[:, :2]
    ate_mm = float(np.sqrt(np.mean(np.sum((aligned - true[:, :2]) ** 2, axis=1))))
    rms = np.sqrt(np.mean(step_error**2, axis=0))
    return OdometryEval(
        poses=len(est_index),
        distance_m=distance_mm / 1000,
        rmse_dx_mm=float(rms[0]),
        rmse_dy_mm=float(rms[1]),
        rmse_dtheta_deg=float(np.degrees(rms[2])),
        final_error_m=final_mm / 1000,
        ate_rmse_m=ate_mm / 1000,
        drift_percent=100 * final_mm / distance_mm if distance_mm > 0 else float("nan"),
    )
