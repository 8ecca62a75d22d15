"""TRACK.json — one tracked target, frame by frame — and the figures: a run's boxes and
confidence, and the One-Pass Evaluation's success and precision curves.

TRACK.json::

    {"sequence": "…", "track_id": 3 | null, "tracker": "geometric", "detector": "learned",
     "reset": "adaptive:10", "frames": [
        {"frame": 0, "camera_box": {"h", "w", "l", "x", "y", "z", "ry"},
         "lidar_box": {"x", "y", "z", "l", "w", "h", "yaw"}, "confidence": 1.0,
         "points": 412, "detector_ran": false, "reset": false}, …],
     "detector_cost_percent": 9.8, "fps": 143.0, "compute_fps": 151.2, …}

Boxes are metres and radians; ``camera_box`` is KITTI's (bottom centre, rectified camera
frame), ``lidar_box`` the box's centre in the Velodyne frame.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from services.lib import kitti
from services.lib.boxes import BOX_FIELDS
from services.tracking.ope import PRECISION_THRESHOLDS_M, SUCCESS_THRESHOLDS, OPEResult
from services.tracking.pipeline import TrackResult

CAMERA_FIELDS = ("h", "w", "l", "x", "y", "z", "ry")


def track_document(result: TrackResult, calibration: kitti.Calibration, **about: object) -> dict:
    """The run as TRACK.json's document; ``about`` (sequence, track_id, tracker, …) first."""
    boxes = result.boxes
    camera = kitti.lidar_to_camera(boxes, calibration)
    frames = [
        {
            "frame": f.frame,
            "camera_box": dict(zip(CAMERA_FIELDS, np.round(c, 4).tolist(), strict=True)),
            "lidar_box": dict(zip(BOX_FIELDS, np.round(b, 4).tolist(), strict=True)),
            "confidence": round(f.confidence, 4),
            "points": f.points,
            "detector_ran": f.detector_ran,
            "reset": f.reset,
        }
        for f, b, c in zip(result.frames, boxes, camera, strict=True)
    ]
    return {
        **about,
        "frames": frames,
        "detector_runs": result.detector_frames,
        "detector_cost_percent": round(result.cost_percent, 3),
        "fps": round(result.fps, 1),
        "compute_fps": round(result.compute_fps, 1),
        "tracker_seconds": round(result.tracker_s, 4),
        "detector_seconds": round(result.detector_s, 4),
        "read_seconds": round(result.read_s, 4),
    }


def read_track(path: Path) -> dict:
    """A TRACK.json's document; ValueError naming what is wrong."""
    try:
        document = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable TRACK.json ({exc})") from None
    frames = document.get("frames") if isinstance(document, dict) else None
    if not isinstance(frames, list) or not frames:
        raise ValueError(f"{path}: a TRACK.json holds a non-empty list of frames")
    for entry in frames:
        box = entry.get("lidar_box") if isinstance(entry, dict) else None
        if (
            not isinstance(box, dict)
            or any(not isinstance(box.get(k), int | float) for k in BOX_FIELDS)
            or not isinstance(entry.get("frame"), int)
        ):
            raise ValueError(
                f"{path}: every frame needs its frame number and lidar_box (x y z l w h yaw)"
            )
    return document


def lidar_boxes(document: dict) -> tuple[list[int], np.ndarray]:
    frames = [entry["frame"] for entry in document["frames"]]
    boxes = np.array(
        [[entry["lidar_box"][k] for k in BOX_FIELDS] for entry in document["frames"]],
        dtype=np.float64,
    )
    return frames, boxes


def plot_run(document: dict, path: Path, truth: np.ndarray | None = None) -> None:
    """The target's path seen from above (detector resets marked) and its confidence and
    points over the frames; with ``truth`` (F, 7), the true path and the centre error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames, boxes = lidar_boxes(document)
    reset = np.array([entry["reset"] for entry in document["frames"]])
    confidence = np.array([entry["confidence"] for entry in document["frames"]])
    figure, (top, bottom) = plt.subplots(1, 2, figsize=(12, 4.5))
    if truth is not None:
        top.plot(truth[:, 0], truth[:, 1], color="0.6", lw=3, label="truth")
    top.plot(boxes[:, 0], boxes[:, 1], color="tab:blue", lw=1, label="tracked")
    top.scatter(
        boxes[reset, 0], boxes[reset, 1], color="tab:red", s=12, zorder=3, label="detector reset"
    )
    top.set(xlabel="x (m, LiDAR frame of each scan)", ylabel="y (m)", title="the target's centre")
    top.axis("equal")
    top.legend(loc="best", fontsize=8)
    bottom.plot(frames, confidence, color="tab:blue", label="confidence")
    bottom.set(xlabel="frame", ylabel="confidence", ylim=(0, 1.05))
    if truth is not None:
        twin = bottom.twinx()
        twin.plot(
            frames,
            np.linalg.norm(boxes[:, :3] - truth[:, :3], axis=1),
            color="tab:orange",
            label="centre error",
        )
        twin.set_ylabel("centre error (m)")
    ran = [f for f, entry in zip(frames, document["frames"], strict=True) if entry["detector_ran"]]
    bottom.vlines(ran, 0, 0.08, color="tab:red", lw=0.8, label="detector ran")
    bottom.legend(loc="lower left", fontsize=8)
    bottom.set_title(f"{document.get('tracker')} tracker, reset {document.get('reset')}")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def plot_ope(results: dict[str, OPEResult], path: Path) -> None:
    """Success and precision curves, one line per named result (Success/Precision in the legend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name, result in results.items():
        left.plot(SUCCESS_THRESHOLDS, result.success_curve, label=f"{name} [{result.success:.1f}]")
        right.plot(
            PRECISION_THRESHOLDS_M, result.precision_curve, label=f"{name} [{result.precision:.1f}]"
        )
    left.set(
        xlabel="3D IoU threshold", ylabel="share of frames", title="Success (OPE)", ylim=(0, 1.02)
    )
    right.set(
        xlabel="centre error threshold (m)",
        ylabel="share of frames",
        title="Precision (OPE)",
        ylim=(0, 1.02),
    )
    for axis in (left, right):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8, loc="lower left" if axis is left else "lower right")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
