"""An estimated trajectory against the truth: per-step errors of the relative motions,
the final position error, the absolute trajectory error and the drift.

Poses are matched by time (within half a frame). The per-step error compares each
estimated motion between consecutive matched poses with the true one, in the first pose's
frame; the ATE is the RMS position error after the rigid planar alignment that fits best
(Umeyama without scale), as evo's ``ape`` reports it. The heading bias is the mean of the
per-step heading errors (what sums into a curved path on a straight run).

Given the final pose's covariance, the final error is also judged against it: the
normalised estimation error squared (NEES, eᵀ P⁻¹ e over x, y and θ: about 3 on average when
the covariance tells the truth) and whether the position error is within twice the
position's σ (the root of the x–y trace).
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
    heading_bias_deg: float
    """The mean per-step heading error (degrees a frame)."""
    final_nees: float | None = None
    """eᵀ P⁻¹ e of the final pose (x, y, θ), when its covariance is given and positive
    definite."""
    final_sigma_xy_m: float | None = None
    final_within_2_sigma: bool | None = None

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


def _matched(estimate: Trajectory2D, truth: Trajectory2D) -> tuple[np.ndarray, ...]:
    """The estimate's indices matched in time, its poses moved to start where the first
    matched true pose is, and those true poses."""
    est_index, true_index = match(estimate, truth)
    est, true = estimate.pose[est_index], truth.pose[true_index]
    return est_index, se2.compose(se2.compose(true[:1], se2.inverse(est[:1])), est), true


def error_along_path(estimate: Trajectory2D, truth: Trajectory2D, most: int = 2000) -> dict:
    """The position error against the distance travelled, and the true path in the
    estimate's frame (both start at the first matched pose), at most ``most`` points (a run
    page's plots): metres."""
    est_index, est, true = _matched(estimate, truth)
    travelled_mm = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(true[:, :2], axis=0).T))])
    error_mm = np.hypot(*(est[:, :2] - true[:, :2]).T)
    start = estimate.pose[est_index[:1]]
    true_in_estimate = se2.compose(se2.compose(start, se2.inverse(true[:1])), true)
    keep = np.unique(np.linspace(0, len(est) - 1, min(most, len(est))).round().astype(int))
    return {
        "distance_m": np.round(travelled_mm[keep] / 1000, 5).tolist(),
        "error_m": np.round(error_mm[keep] / 1000, 6).tolist(),
        "truth_x_m": np.round(true_in_estimate[keep, 0] / 1000, 5).tolist(),
        "truth_y_m": np.round(true_in_estimate[keep, 1] / 1000, 5).tolist(),
    }


def evaluate(
    estimate: Trajectory2D, truth: Trajectory2D, final_covariance: np.ndarray | None = None
) -> OdometryEval:
    """The estimate against the truth; ``final_covariance`` (3 × 3: mm², mm·rad, rad²) of
    the estimate's last pose, when known."""
    est_index, est, true = _matched(estimate, truth)
    step_error = se2.relative(est) - se2.relative(true)
    step_error[:, 2] = se2.wrap(step_error[:, 2])
    distance_mm = float(np.hypot(*np.diff(truth.pose[:, :2], axis=0).T).sum())
    final_mm = float(np.hypot(*(est[-1, :2] - true[-1, :2])))
    fit = align_rigid(est[:, :2], true[:, :2])
    aligned = se2.compose(fit, est)[:, :2]
    ate_mm = float(np.sqrt(np.mean(np.sum((aligned - true[:, :2]) ** 2, axis=1))))
    rms = np.sqrt(np.mean(step_error**2, axis=0))
    judged = {}
    if final_covariance is not None and est_index[-1] == len(estimate) - 1:
        error = est[-1] - true[-1]
        error[2] = se2.wrap(error[2])
        covariance = np.asarray(final_covariance, dtype=np.float64)
        sigma_mm = float(np.sqrt(covariance[0, 0] + covariance[1, 1]))
        # a covariance without spread in some direction (a model that claims no error in
        # it) cannot judge the error: its NEES is unmeasured
        positive = bool(np.all(np.linalg.eigvalsh(covariance) > 0))
        judged = {
            "final_nees": float(error @ np.linalg.solve(covariance, error)) if positive else None,
            "final_sigma_xy_m": sigma_mm / 1000,
            "final_within_2_sigma": bool(final_mm <= 2 * sigma_mm),
        }
    return OdometryEval(
        poses=len(est_index),
        distance_m=distance_mm / 1000,
        rmse_dx_mm=float(rms[0]),
        rmse_dy_mm=float(rms[1]),
        rmse_dtheta_deg=float(np.degrees(rms[2])),
        final_error_m=final_mm / 1000,
        ate_rmse_m=ate_mm / 1000,
        drift_percent=100 * final_mm / distance_mm if distance_mm > 0 else float("nan"),
        heading_bias_deg=float(np.degrees(step_error[:, 2].mean())),
        **judged,
    )
