"""Detections as KITTI's result files (``vista tracking detect``): one ``label_2`` file a scan,
a line a car in the camera's view, scored against labels when they are given."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.lib import kitti
from services.tracking.detection_eval import combine, in_view, tally_scan
from services.tracking.detections import Detections
from services.tracking.run import make_detector

IMAGE_SIZE = (1242, 375)


def result_labels(detections: Detections, calibration: kitti.Calibration) -> kitti.Labels:
    """The detections in the camera's view as KITTI result rows (truncation and occlusion
    −1, as KITTI's result files have them)."""
    shown = (
        detections.select(in_view(detections.boxes, calibration, IMAGE_SIZE))
        if len(detections)
        else detections
    )
    count = len(shown)
    camera = kitti.lidar_to_camera(shown.boxes, calibration)
    image, _ = kitti.image_boxes(shown.boxes, calibration, IMAGE_SIZE)
    return kitti.Labels(
        frame=np.zeros(count, int),
        track_id=np.full(count, -1),
        type=("Car",) * count,
        truncated=np.full(count, -1.0),
        occluded=np.full(count, -1),
        alpha=kitti.observation_angle(camera),
        bbox=image,
        camera_box=camera,
        score=shown.scores,
    )


def _pairs(
    scan: Path, calib: Path, out: Path, labels: Path | None
) -> list[tuple[Path, Path, Path, Path | None]]:
    if scan.is_dir():
        scans = sorted(scan.glob("*.bin"))
        if not scans:
            raise ValueError(f"{scan}: no .bin scans")
        pairs = []
        for path in scans:
            calibration = calib / f"{path.stem}.txt" if calib.is_dir() else calib
            if not calibration.exists():
                raise ValueError(f"{calibration}: no calibration for {path.name}")
            label = (
                labels / f"{path.stem}.txt" if labels is not None and labels.is_dir() else labels
            )
            if label is not None and not label.exists():
                label = None  # a drive labelled every other frame: its other scans are not scored
            pairs.append((path, calibration, out / f"{path.stem}.txt", label))
        if labels is not None and all(pair[3] is None for pair in pairs):
            raise ValueError(f"--labels {labels}: no label file is named as a scan is")
        return pairs
    if not scan.exists():
        raise ValueError(f"{scan}: no such scan")
    if calib.is_dir():
        raise ValueError(f"--calib {calib}: a folder; for one scan give its calibration file")
    return [(scan, calib, out, labels)]


def detect_files(
    scan: Path,
    calib: Path,
    out: Path,
    *,
    detector: str = "learned",
    model: Path | None = None,
    threshold: float | None = None,
    labels: Path | None = None,
    threads: int = 1,
) -> str:
    """Detect cars in a scan (or a folder of scans) and write label_2 results; a one-line
    summary (with the scores when ``labels`` are given)."""
    the_detector = make_detector(detector, model, threads)
    if threshold is not None:
        the_detector.threshold = threshold
    tallies, written = [], 0
    for scan_path, calib_path, out_path, label_path in _pairs(
        Path(scan), Path(calib), Path(out), labels
    ):
        calibration = kitti.read_calibration(calib_path)
        found = the_detector.detect(kitti.read_velodyne(scan_path))
        rows = result_labels(found, calibration)
        out_path.parent.mkdir(parents=True, exist_ok=True)
        out_path.write_text(kitti.format_labels(rows, tracking=False))
        written += len(rows)
        if label_path is not None:
            tallies.append(tally_scan(found, kitti.read_object_labels(label_path), calibration))
    summary = f"{written} cars in view written to {out}"
    if tallies:
        scores = combine(tallies, 40.0, the_detector.threshold)
        summary += f"; against the labels of {len(tallies)} scans: {scores.describe()}"
    return summary
