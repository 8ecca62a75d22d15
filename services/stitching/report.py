"""REPORT.json of a stitch: overlap quality, what clean-up and ICP did, and (in simulation)
the error against the truth. One builder for ``vista stitching stitch`` and the
``stitching.stitch`` job (``run.stitch_files``)."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from services.lib.pointcloud.transforms import pose_error
from services.stitching.files import SimulatedTruth
from services.stitching.icp import IcpConfig
from services.stitching.quality import QualityReport, quality_report
from services.stitching.stitch import StitchConfig, StitchResult


def distance_to_truth_mm(truth: SimulatedTruth, points_base: np.ndarray) -> np.ndarray:
    """Distance (mm) of base-frame points to the simulated part's true surface."""
    from services.lib.pointcloud.scan_sim import COMPONENTS, Scanner, SensorModel

    scanner = Scanner(COMPONENTS[truth.component](), truth.base_T_part, SensorModel())
    return scanner.distance_to_surface_mm(points_base)


def stitch_report(
    result: StitchResult,
    *,
    config: StitchConfig,
    calibration: dict,
    truth: SimulatedTruth | None = None,
) -> tuple[QualityReport, dict]:
    """The quality report and the whole REPORT.json document."""
    true_distance = model_bounds = None
    if truth is not None:
        true_distance = distance_to_truth_mm(truth, result.cloud.points)
        model_bounds = truth.model_bounds_mm
    quality = quality_report(
        [s.points for s in result.scans],
        result.cloud.points,
        model_bounds_mm=model_bounds,
        true_distance_mm=true_distance,
    )
    document = {
        "scans": len(result.scans),
        "points": len(result.cloud.points),
        "outliers_removed": [s.outliers for s in result.scans],
        "isolated_removed": result.isolated_removed,
        "calibration": {
            "method": calibration.get("method"),
            "sigma_translation_mm": calibration.get("sigma_translation_mm"),
            "sigma_rotation_deg": calibration.get("sigma_rotation_deg"),
        },
        "config": {k: v for k, v in asdict(config).items() if k != "icp"},
        "icp": None if config.icp is None else _icp_json(config.icp, result),
        "seconds": result.seconds,
        **quality.to_json(),
    }
    if truth is not None:
        true_base_T_scan = truth.scan_base_T_flange @ truth.flange_T_sensor
        errors = np.array(
            [pose_error(a, b) for a, b in zip(result.base_T_scan, true_base_T_scan, strict=True)]
        )
        document["scan_pose_error"] = {
            "translation_mm": errors[:, 0].tolist(),
            "rotation_deg": errors[:, 1].tolist(),
            "mean_translation_mm": float(errors[:, 0].mean()),
            "max_translation_mm": float(errors[:, 0].max()),
            "max_rotation_deg": float(errors[:, 1].max()),
        }
    return quality, _finite(document)


def _finite(value: object) -> object:
    """NaN and infinity (no overlap, no points) as null: JSON has no NaN."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _icp_json(config: IcpConfig, result: StitchResult) -> dict:
    return {
        "method": config.method,
        "start": config.start,
        "max_distance_mm": config.max_distance_mm,
        "robot_sigma_mm": config.robot_sigma_mm,
        "robot_sigma_deg": config.robot_sigma_deg,
        "bound_probability": config.bound_probability,
        "scans": [
            {
                "moved_mm": a.moved_mm,
                "moved_deg": a.moved_deg,
                "mahalanobis": a.mahalanobis,
                "fitted_mahalanobis": a.fitted_mahalanobis,
                "clipped": a.clipped,
                "iterations": a.iterations,
                "correspondences": a.correspondences,
                "rmse_mm": a.rmse_mm,
            }
            for a in result.alignments or []
        ],
    }
