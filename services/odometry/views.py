"""What an odometry run's page shows: the path in the floor plane with its 1σ band, the
flagged and warned pairs on it, the true path and the error against distance when the
sequence had truth, and the run's figures (``contract.views``); and its 3D scene, the path
as a line strip (``contract.scene``)."""

from __future__ import annotations

import numpy as np

from contract.scene import JobScene, LineGroup, Polyline
from contract.views import Figure, Figures, JobFiles, Line, Plot
from services.odometry.kinds import EVALUATION, RUN_REPORT, TRAJECTORY
from services.odometry.tum import read_tum

MOST_POINTS = 2000
"""A path longer than this is drawn through this many of its poses (marks stay exact)."""


def run_view(files: JobFiles) -> list:
    report = files.json(RUN_REPORT.file_name()) or {}
    evaluation = files.json(EVALUATION.file_name())
    trajectory = read_tum(files.outputs[TRAJECTORY.file_name()])
    xy_m = trajectory.pose[:, :2] / 1000
    sigma_m = np.asarray(report.get("sigma_xy_mm", np.zeros(len(xy_m))), dtype=float) / 1000
    keep = np.unique(np.linspace(0, len(xy_m) - 1, min(MOST_POINTS, len(xy_m))).round().astype(int))
    lines = [
        Line("estimate (±1σ)", _list(xy_m[keep, 0]), _list(xy_m[keep, 1]), _list(sigma_m[keep]))
    ]
    if evaluation and "along_path" in evaluation:
        along = evaluation["along_path"]
        lines.append(Line("truth", along["truth_x_m"], along["truth_y_m"]))
    for what, key in (("flagged pairs", "flag"), ("warned pairs", "warning")):
        ends = [p["pair"] + 1 for p in report.get("pairs_detail", []) if p.get(key)]
        if ends:
            lines.append(Line(what, _list(xy_m[ends, 0]), _list(xy_m[ends, 1]), style="points"))
    panels: list = [Plot("Path in the floor plane", "x (m)", "y (m)", lines, equal_axes=True)]
    if evaluation and "along_path" in evaluation:
        along = evaluation["along_path"]
        panels.append(
            Plot(
                "Position error against distance",
                "distance travelled (m)",
                "position error (mm)",
                [Line("error", along["distance_m"], [1000 * e for e in along["error_m"]])],
            )
        )
    panels.append(Figures("Run", _run_figures(files.result, report, evaluation)))
    return panels


def _run_figures(result: dict, report: dict, evaluation: dict | None) -> list[Figure]:
    figures = [
        Figure("method", result.get("method", report.get("method"))),
        Figure("frames", report.get("frames")),
        Figure("pairs per second", report.get("pairs_per_s"), "pairs/s"),
        Figure("flagged pairs", report.get("flagged")),
        Figure("warned pairs", report.get("warned")),
        Figure("final 1σ (x, y)", report.get("final_sigma_xy_mm"), "mm"),
    ]
    if evaluation is None:
        note = "the sequence had no truth.tum"
        return figures + [Figure(label, None, note=note) for label in ("drift", "final error")]
    return figures + [
        Figure("distance", round(evaluation["distance_m"], 3), "m"),
        Figure("drift", _rounded(evaluation["drift_percent"], 3), "% of distance"),
        Figure("final error", _rounded(1000 * evaluation["final_error_m"], 3), "mm"),
        Figure("ATE RMSE", _rounded(1000 * evaluation["ate_rmse_m"], 3), "mm"),
        Figure(
            "RMSE δx, δy", f"{evaluation['rmse_dx_mm']:.4f}, {evaluation['rmse_dy_mm']:.4f}", "mm"
        ),
        Figure("RMSE δθ", _rounded(evaluation["rmse_dtheta_deg"], 5), "°"),
        Figure(
            "final error within 2σ",
            None
            if evaluation.get("final_within_2_sigma") is None
            else ("yes" if evaluation["final_within_2_sigma"] else "no"),
            note="no covariance of the last pose",
        ),
    ]


def _list(values: np.ndarray) -> list[float]:
    return np.round(values.astype(float), 5).tolist()


def _rounded(value: float | None, digits: int) -> float | None:
    return None if value is None or not np.isfinite(value) else round(float(value), digits)


def run_scene(files: JobFiles, max_points: int) -> JobScene:
    """The path as a line strip on the floor (its 1σ per pose in the line's extras), the
    true path beside it when the sequence had truth; the run's figures in the extras."""
    report = files.json(RUN_REPORT.file_name()) or {}
    evaluation = files.json(EVALUATION.file_name())
    trajectory = read_tum(files.outputs[TRAJECTORY.file_name()])
    on_floor = np.column_stack([trajectory.pose[:, :2], np.zeros(len(trajectory))])
    path = Polyline(
        "estimate",
        on_floor.tolist(),
        "strip",
        {"sigma_xy_mm": report.get("sigma_xy_mm", []), "frames": len(trajectory)},
    )
    groups = [LineGroup("path", "path", (0.12, 0.47, 0.71, 1.0), (path,))]
    if evaluation and "along_path" in evaluation:
        along = evaluation["along_path"]
        xy_mm = 1000 * np.column_stack([along["truth_x_m"], along["truth_y_m"]])
        truth = np.column_stack([xy_mm, np.zeros(len(xy_mm))])
        groups.append(
            LineGroup(
                "truth",
                "truth",
                (0.84, 0.15, 0.16, 1.0),
                (Polyline("truth", truth.tolist(), "strip", {}),),
            )
        )
    figures = {k: v for k, v in files.result.items() if not isinstance(v, dict)}
    if evaluation:
        figures |= {k: v for k, v in evaluation.items() if isinstance(v, int | float)}
    return JobScene(
        lines=tuple(groups),
        frame="the first camera's floor frame (x, y on the floor)",
        extras={"figures": figures},
    )
