"""What ``vista stitching calibrate|stitch`` and the ``stitching.calibrate|stitch`` jobs do:
one core function per verb (files and the kind's parameters in, a result out) that the
command and the job handler both call; they only say where the files are and what is shown.

Errors are ``ValueError``s naming the file at fault by its path (``StitchingFileError``,
``PlyError``, ``CalibrationError``): a command prints them, a job names its inputs instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.vocabulary import Progress
from services.lib.pointcloud.ply import PlyError, read_ply, write_ply
from services.stitching.calibration import HandEye, calibrate
from services.stitching.files import read_handeye, read_pairs, read_truth
from services.stitching.kinds import CalibrateParams, StitchParams
from services.stitching.quality import QualityReport, histogram_png
from services.stitching.report import stitch_report
from services.stitching.stitch import StitchConfig, StitchResult, stitch


def calibrate_pairs(pairs: Path, params: CalibrateParams) -> HandEye:
    """The hand-eye calibration of PAIRS.json by ``params.method``, weighed by (and keeping)
    the noise ``params`` state."""
    base_T_flange, sensor_T_target = read_pairs(pairs)
    return calibrate(base_T_flange, sensor_T_target, method=params.method, noise=params)


@dataclass(frozen=True)
class Stitched:
    result: StitchResult
    quality: QualityReport
    report: dict
    """REPORT.json."""

    def summary(self) -> list[str]:
        """What the stitch did, a line each: the points, the scans and the overlap's
        distances; what ICP moved (with ICP); the true errors (with a simulation's truth)."""
        o = self.quality.overall
        lines = [
            f"{len(self.result.cloud.points)} points from {len(self.result.scans)} scans; "
            f"overlap of {len(self.quality.pairs)} pairs: mean {o.mean_mm:.4f} mm, std "
            f"{o.std_mm:.4f}, p90 {o.p90_mm:.4f}, max {o.max_mm:.3f}"
        ]
        alignments = self.result.alignments
        if alignments is not None:
            lines.append(
                f"ICP {self.report['icp']['method']}: moved scans by up to "
                f"{max(a.moved_mm for a in alignments):.3f} mm, "
                f"{max(a.moved_deg for a in alignments):.4f}°; "
                f"{sum(a.clipped for a in alignments)} cut back to the kinematic bound"
            )
        if self.quality.true_error is not None:
            t, pose = self.quality.true_error, self.report["scan_pose_error"]
            lines.append(
                f"true error to the surface: mean {t.mean_mm:.4f} mm, p90 {t.p90_mm:.4f}; scan "
                f"poses: mean {pose['mean_translation_mm']:.4f} mm, max "
                f"{pose['max_translation_mm']:.4f} mm / {pose['max_rotation_deg']:.4f}°"
            )
        return lines


def stitch_files(
    scans: list[Path],
    base_T_flange: np.ndarray,
    handeye: Path,
    params: StitchParams,
    *,
    truth: Path | None = None,
    progress: Progress | None = None,
) -> Stitched:
    """The PLY ``scans`` taken at ``base_T_flange`` (n, 4, 4) stitched with the calibration
    HANDEYE.json as ``params`` ask, and the overlap quality; with a simulation's
    ``truth.json``, the error against the true surface and poses too."""
    report = progress or (lambda fraction, message: None)
    flange_T_sensor, calibration = read_handeye(handeye)
    config = StitchConfig.from_params(params, calibration)
    simulated = None if truth is None else read_truth(truth)
    if simulated is not None and len(simulated.scan_base_T_flange) != len(scans):
        raise ValueError(
            f"{truth} holds {len(simulated.scan_base_T_flange)} scans, the scan list {len(scans)}"
        )
    clouds = []
    for i, path in enumerate(scans):
        report(0.3 * i / len(scans), f"reading scan {i + 1} of {len(scans)}")
        try:
            clouds.append(read_ply(path))
        except PlyError as exc:
            raise PlyError(f"{path}: {exc}") from None
    result = stitch(
        clouds,
        base_T_flange,
        flange_T_sensor,
        config=config,
        progress=lambda fraction, message: report(0.3 + 0.5 * fraction, message),
    )
    report(0.8, "measuring the overlap quality")
    quality, document = stitch_report(
        result, config=config, calibration=calibration, truth=simulated
    )
    report(1.0, f"stitched {len(scans)} scans")
    return Stitched(result, quality, document)


def write_stitched(stitched: Stitched, cloud: Path, plot: Path) -> None:
    """The stitched cloud (PLY) and the overlap histogram (PNG)."""
    write_ply(cloud, stitched.result.cloud, comments=("vista stitched, base frame, mm",))
    histogram_png(stitched.quality, plot)
