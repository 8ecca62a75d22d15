"""What ``vista odometry run`` and ``eval`` write besides the TUM file: the run's JSON
(per pair: motion, confidence, flag; per pose: uncertainty) and the plot."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from services.odometry.evaluate import match
from services.odometry.run import OdometryRun
from services.odometry.tum import Trajectory2D, write_tum


def write_run(
    run: OdometryRun,
    trajectory_path: Path,
    report_path: Path,
    plot_path: Path | None = None,
    truth: Trajectory2D | None = None,
) -> None:
    """A run's files: the trajectory (TUM), its JSON and, if asked, its plot (against the
    truth when given)."""
    write_tum(trajectory_path, run.trajectory)
    report_path.write_text(json.dumps(run_document(run), indent=1) + "\n")
    if plot_path is not None:
        trajectory_png(run.trajectory, plot_path, truth, run.sigma_xy_mm)


def run_document(run: OdometryRun) -> dict:
    steps = run.steps
    return {
        "method": run.method,
        "frames": len(run.trajectory),
        "pairs": len(steps.motion),
        "flagged": run.flagged,
        "warned": run.warned,
        "pairs_per_s": round(run.pairs_per_s, 1),
        "final_sigma_xy_mm": round(float(run.sigma_xy_mm[-1]), 3),
        "final_covariance": {
            "units": "mm², mm·rad, rad² (x, y, θ)",
            "matrix": run.covariance[-1].tolist(),
        },
        "pairs_detail": [
            {
                "pair": k,
                "dx_mm": round(float(m[0]), 5),
                "dy_mm": round(float(m[1]), 5),
                "dtheta_deg": round(float(np.degrees(m[2])), 5),
                "confidence": round(float(c), 3),
                "flag": reason,
                "warning": warning,
            }
            for k, (m, c, reason, warning) in enumerate(
                zip(
                    steps.motion,
                    steps.confidence,
                    steps.reasons,
                    steps.warnings,
                    strict=True,
                )
            )
        ],
        "sigma_xy_mm": [round(float(v), 3) for v in run.sigma_xy_mm],
        "sigma_theta_deg": [round(float(np.degrees(np.sqrt(c[2, 2]))), 5) for c in run.covariance],
    }


def final_covariance(report_path: Path) -> np.ndarray | None:
    """The final pose's covariance a TRAJ.json holds (None: not there, or an older file)."""
    try:
        document = json.loads(report_path.read_text())
        return np.array(document["final_covariance"]["matrix"], dtype=np.float64).reshape(3, 3)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def trajectory_png(
    estimate: Trajectory2D,
    path: Path,
    truth: Trajectory2D | None = None,
    sigma_mm: np.ndarray | None = None,
) -> None:
    """The path seen from above (estimate, truth), and, with the truth, the position error
    against the distance travelled (with the estimate's 1σ where given)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 2 if truth is not None else 1
    figure, axes = plt.subplots(1, panels, figsize=(6.5 * panels, 5.5), squeeze=False)
    top = axes[0, 0]
    if truth is not None:
        top.plot(truth.pose[:, 0] / 1000, truth.pose[:, 1] / 1000, color="0.3", lw=2, label="truth")
    top.plot(
        estimate.pose[:, 0] / 1000,
        estimate.pose[:, 1] / 1000,
        color="tab:orange",
        lw=1.2,
        label="estimate",
    )
    top.plot([0], [0], "ko", ms=4)
    _equal_and_readable(top, estimate.pose[:, :2] / 1000)
    top.invert_yaxis()  # y along the image rows: drawn as the camera sees it
    top.set_xlabel("x (m, camera 0's columns)")
    top.set_ylabel("y (m, camera 0's rows)")
    top.legend(loc="best")
    top.set_title("trajectory")
    if truth is not None:
        est_index, true_index = match(estimate, truth)
        true = truth.pose[true_index]
        distance = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(true[:, :2], axis=0).T))])
        error = np.hypot(*(estimate.pose[est_index, :2] - true[:, :2]).T)
        side = axes[0, 1]
        side.plot(distance / 1000, error, color="tab:red", label="position error")
        if sigma_mm is not None:
            side.fill_between(
                distance / 1000,
                0,
                np.asarray(sigma_mm)[est_index],
                color="tab:blue",
                alpha=0.2,
                label="estimated 1σ",
            )
        side.set_xlabel("distance travelled (m)")
        side.set_ylabel("error (mm)")
        side.legend(loc="upper left")
        side.set_title("error against distance")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _equal_and_readable(axes, xy_m: np.ndarray) -> None:  # noqa: ANN001 - matplotlib axes
    """Equal scales, each axis spanning at least a third of the other's: a straight path
    would otherwise be a line in a strip too thin to read."""
    low, high = xy_m.min(axis=0), xy_m.max(axis=0)
    centre, span = (low + high) / 2, np.maximum(high - low, 1e-3)
    side = np.maximum(span, span.max() / 3) * 1.1
    axes.set_xlim(centre[0] - side[0] / 2, centre[0] + side[0] / 2)
    axes.set_ylim(centre[1] - side[1] / 2, centre[1] + side[1] / 2)
    axes.set_aspect("equal", adjustable="datalim")
