"""Detections as KITTI's result files (``vista tracking detect``): one ``label_2`` file a scan,
a line a car in the camera's view, scored against labels when they are given; and a whole
sequence's detections as one document (the ``tracking.detect`` job's DETECTIONS.json), with
the camera images' boxes drawn.

DETECTIONS.json::

    {"detector": "learned", "threshold": 0.5, "near_m": 40.0, "ms_per_scan": 21.7,
     "scans": [{"frame": 4, "ms": 20.9,
                "boxes": [[x, y, z, l, w, h, yaw], …], "scores": [0.93, …],
                "in_view": [true, …], "image_boxes": [[left, top, right, bottom], …],
                "scored": true, "true_positive": [true, …], "ignored": [false, …],
                "cars_near": 3, "found_near": 2, "missed": [[x, y, z, l, w, h, yaw], …]}, …]}

Boxes are the LiDAR frame's (centre, metres, radians); ``image_boxes`` are pixels of image
2 (KITTI's 1242 × 375 unless the job was given the images); ``true_positive``, ``ignored``,
``cars_near`` (the labelled cars within ``near_m``), ``found_near`` (those a detection
matched) and ``missed`` (the others) only for scans with labels (``scored``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from services.lib import kitti
from services.tracking.detection_eval import combine, in_view, match_scan
from services.tracking.detections import Detections
from services.tracking.kinds import DetectParams
from services.tracking.pipeline import Detector
from services.tracking.run import make_detector
from services.tracking.sequence import Sequence

IMAGE_SIZE = (1242, 375)
NEAR_M = 40.0
"""Recall is judged over the labelled cars this near (bird's-eye distance)."""


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


def detector_for(params: DetectParams, model: Path | None, threads: int = 1) -> Detector:
    """The detector ``params`` name (the learned one: ``model``, else the shipped one),
    keeping its boxes from ``params.threshold`` (None: from its own)."""
    detector = make_detector(params.detector, model, threads)
    if params.threshold is not None:
        detector.threshold = params.threshold
    return detector


def detect_files(
    scan: Path,
    calib: Path,
    out: Path,
    params: DetectParams,
    *,
    model: Path | None = None,
    labels: Path | None = None,
    threads: int = 1,
) -> str:
    """Detect cars in a scan (or a folder of scans) as ``params`` say and write label_2
    results; a one-line summary (with the scores when ``labels`` are given)."""
    the_detector = detector_for(params, model, threads)
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
            tallies.append(
                match_scan(found, kitti.read_object_labels(label_path), calibration).tally()
            )
    summary = f"{written} cars in view written to {out}"
    if tallies:
        scores = combine(tallies, NEAR_M, the_detector.threshold)
        summary += f"; against the labels of {len(tallies)} scans: {scores.describe()}"
    return summary


def detect_sequence(
    sequence: Sequence,
    detector: Detector,
    *,
    image_sizes: dict[int, tuple[int, int]] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Every scan's detections (see DETECTIONS.json in the module docstring), matched to
    the labels on the frames the sequence labels; ``image_sizes`` the (width, height) of
    the camera images given, by frame."""
    image_sizes = image_sizes or {}
    scored = labelled_frames(sequence)
    scans, tallies = [], []
    for done, frame in enumerate(sequence.frames):
        points = sequence.points(frame)
        started = time.perf_counter()
        found = detector.detect(points)
        seconds = time.perf_counter() - started
        image, _ = kitti.image_boxes(
            found.boxes, sequence.calibration, image_sizes.get(frame, IMAGE_SIZE)
        )
        scan = {
            "frame": frame,
            "ms": round(1000 * seconds, 2),
            "boxes": np.round(found.boxes, 3).tolist(),
            "scores": np.round(found.scores, 3).tolist(),
            "in_view": (
                in_view(found.boxes, sequence.calibration, IMAGE_SIZE).tolist()
                if len(found)
                else []
            ),
            "image_boxes": np.round(image, 1).tolist(),
            "scored": frame in scored,
        }
        if frame in scored:
            labels = sequence.labels.select(sequence.labels.frame == frame)
            match = match_scan(found, labels, sequence.calibration, near_m=NEAR_M)
            tallies.append(match.tally())
            scan |= {
                "true_positive": match.true_positive.tolist(),
                "ignored": match.ignored.tolist(),
                "cars_near": tallies[-1].cars_near,
                "found_near": tallies[-1].found_near,
                "missed": np.round(match.cars[match.near & ~match.found], 3).tolist(),
            }
        scans.append(scan)
        if progress is not None:
            progress(done + 1, len(sequence.frames))
    times = [s["ms"] for s in scans]
    document = {
        "detector": detector.name,
        "threshold": float(detector.threshold),
        "near_m": NEAR_M,
        "ms_per_scan": round(float(np.mean(times)), 2),
        "scans": scans,
    }
    if tallies:
        document["evaluation"] = combine(tallies, NEAR_M, detector.threshold).document()
    return document


def labelled_frames(sequence: Sequence) -> set[int]:
    """The frames a sequence's labels cover: every ``label_step``-th one from its first
    labelled frame to its last (a labelled frame with no object in it included)."""
    if sequence.labels is None or not len(sequence.labels):
        return set()
    first, last = int(sequence.labels.frame.min()), int(sequence.labels.frame.max())
    return set(range(first, last + 1, sequence.label_step)) & set(sequence.frames)


BOX_COLOURS_RGB = {
    "found": (40, 200, 70),
    "false": (230, 40, 40),
    "unjudged": (255, 200, 0),
    "missed": (170, 170, 170),
}
"""A detection that matched a labelled car, one that did not, one not judged (no labels,
a van, DontCare, out of view), and a labelled car no detection found."""


def box_verdicts(scan: dict) -> list[str]:
    """Each detection of a DETECTIONS.json scan as a ``BOX_COLOURS_RGB`` key."""
    if not scan.get("scored"):
        return ["unjudged"] * len(scan["scores"])
    return [
        "found" if hit else "unjudged" if (skip or not seen) else "false"
        for hit, skip, seen in zip(
            scan["true_positive"], scan["ignored"], scan["in_view"], strict=True
        )
    ]


def draw_detections(
    image_rgb: np.ndarray, scan: dict, calibration: kitti.Calibration
) -> np.ndarray:
    """The camera image with the scan's boxes in view drawn on it (coloured by verdict,
    each with its score) and the labelled cars it missed in grey."""
    import cv2

    out = np.ascontiguousarray(image_rgb.copy())
    height, width = out.shape[:2]
    thickness = max(1, round(width / 600))
    shown = []
    missed = np.asarray(scan.get("missed", []), dtype=np.float64).reshape(-1, 7)
    if len(missed):
        ahead = in_view(missed, calibration, (width, height))
        boxes, _ = kitti.image_boxes(missed[ahead], calibration, (width, height))
        shown += [(box, "missed", BOX_COLOURS_RGB["missed"]) for box in boxes]
    found = sorted(  # the best drawn last, its score on top
        zip(scan["scores"], scan["image_boxes"], scan["in_view"], box_verdicts(scan), strict=True),
        key=lambda row: row[0],
    )
    shown += [
        (box, f"{score:.2f}", BOX_COLOURS_RGB[verdict])
        for score, box, seen, verdict in found
        if seen
    ]
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.4 * thickness
    corners = [tuple(int(round(v)) for v in box) for box, _, _ in shown]
    sizes = [cv2.getTextSize(text, font, scale, 1)[0] for _, text, _ in shown]
    places = label_places(corners, [(w + 4, h + 4) for w, h in sizes], (width, height))
    for (left, top, right, bottom), (_, _, colour) in zip(corners, shown, strict=True):
        cv2.rectangle(out, (left, top), (right, bottom), colour, thickness)
    for (x, y), (width_px, height_px), (_, text, colour) in zip(places, sizes, shown, strict=True):
        cv2.rectangle(out, (x, y), (x + width_px + 4, y + height_px + 4), colour, -1)
        cv2.putText(out, text, (x + 2, y + height_px + 1), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def label_places(
    boxes: list[tuple[int, int, int, int]],
    sizes: list[tuple[int, int]],
    image_size: tuple[int, int],
) -> list[tuple[int, int]]:
    """Where each box's label goes (its top-left corner, px): on the box's top edge, else
    just under its bottom edge, else further down the box, the first place that overlaps
    no label placed before it and lies in the image (the last try when none is free)."""
    width, height = image_size
    placed: list[tuple[int, int, int, int]] = []
    out = []
    for (left, top, _, bottom), (w, h) in zip(boxes, sizes, strict=True):
        x = min(max(left, 0), max(width - w, 0))
        tries = [top - h, bottom] + [top + k * h for k in range(1, 8)]
        for y in tries:
            y = min(max(y, 0), max(height - h, 0))
            free = all(
                x + w <= a or a + c <= x or y + h <= b or b + d <= y for a, b, c, d in placed
            )
            if free:
                break
        placed.append((x, y, w, h))
        out.append((x, y))
    return out
