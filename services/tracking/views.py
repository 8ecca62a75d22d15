"""What a tracking run's page shows: the confidence over the frames with the detector's runs
and the resets marked, the box's path seen from above, and the run's figures
(``contract.views``); and its 3D scene, the scans with the box moving through them
(``contract.scene``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contract.scene import JobScene, MovingBox, PointSet
from contract.views import Figure, Figures, JobFiles, Line, Plot
from services.tracking.kinds import EVALUATION, TRACK_REPORT


def track_view(files: JobFiles) -> list:
    document = files.json(TRACK_REPORT.file_name()) or {}
    frames = document.get("frames", [])
    index = [float(f["frame"]) for f in frames]
    confidence = [float(f["confidence"]) for f in frames]
    lines = [Line("confidence", index, confidence)]
    for what, key in (("detector ran", "detector_ran"), ("reset", "reset")):
        marked = [k for k, f in enumerate(frames) if f.get(key)]
        if marked:
            lines.append(
                Line(
                    what,
                    [index[k] for k in marked],
                    [confidence[k] for k in marked],
                    style="points",
                )
            )
    x = [float(f["lidar_box"]["x"]) for f in frames]
    y = [float(f["lidar_box"]["y"]) for f in frames]
    panels: list = [
        Plot("Confidence over the drive", "frame", "confidence", lines),
        Plot(
            "The box's path from above (LiDAR frame)",
            "x (m)",
            "y (m)",
            [Line("box centre", x, y)],
            equal_axes=True,
        ),
    ]
    figures = [
        Figure("frames", len(frames)),
        Figure("detector runs", document.get("detector_runs")),
        Figure("detector cost", document.get("detector_cost_percent"), "% of frames"),
        Figure("speed", document.get("fps"), "frames/s"),
        Figure("resets", sum(1 for f in frames if f.get("reset"))),
    ]
    evaluation = files.json(EVALUATION.file_name())
    ope = (evaluation or {}).get("ope")
    if ope is None:
        why = (evaluation or {}).get("unmeasured", "the drive had no labels")
        figures.append(Figure("success / precision", None, note=why))
    else:
        figures += [
            Figure("success (OPE, AUC of IoU)", ope["success"], "%"),
            Figure("precision (OPE, AUC of centre error to 2 m)", ope["precision"], "%"),
            Figure("mean IoU", ope["mean_iou"]),
            Figure("mean centre error", ope["mean_centre_error_m"], "m"),
            Figure("frames scored", ope["frames"]),
        ]
        success, precision = ope["success_curve"], ope["precision_curve"]
        panels += [
            Plot("Success (OPE)", "overlap threshold (IoU)", "share of frames",
                 [Line("success", success["iou_thresholds"], success["share"])]),
            Plot("Precision (OPE)", "centre error threshold (m)", "share of frames",
                 [Line("precision", precision["error_thresholds_m"], precision["share"])]),
        ]  # fmt: skip
    return panels + [Figures("Run", figures)]


SCENE_RADIUS_M = 30.0
"""A scan is kept this far around the tracked box (what a viewer looks at)."""
HEIGHT_COLOURS = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]]
)
"""Viridis at five heights, low to high."""


def track_scene(files: JobFiles, max_points: int) -> JobScene:
    """The drive as the tracker saw it: each frame's scan within ``SCENE_RADIUS_M`` of the
    box (coloured by height; the point budget shared among the frames), shown for its frame,
    and the tracked box moving one key a frame — with the labelled box when the drive had
    labels for the track. In each scan's own LiDAR frame (x forward, y left, z up)."""
    import tempfile

    from services.lib.boxes import check_boxes
    from services.tracking.lidar_archive import extract_lidar
    from services.tracking.report import lidar_boxes
    from services.tracking.sequence import open_sequence, tracklets

    document = files.json(TRACK_REPORT.file_name())
    if document is None:
        raise ValueError("the run wrote no track.json")
    frames, boxes = lidar_boxes(document)
    archives = list(files.inputs_of_kind("lidar").values())
    if len(archives) != 1:
        raise ValueError("the run's LiDAR sequence is not among its inputs")
    per_frame = max(100, max_points // len(frames))
    frame_s = 0.1  # KITTI's LiDAR turns at 10 Hz
    times_s = np.arange(len(frames)) * frame_s
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory(prefix="vista-track-scene-") as folder:
        extract_lidar(archives[0], Path(folder))
        sequence = open_sequence(Path(folder))
        scans = []
        for k, (frame, box) in enumerate(zip(frames, boxes, strict=True)):
            points = sequence.points(int(frame))[:, :3]
            near = points[np.hypot(*(points[:, :2] - box[:2]).T) <= SCENE_RADIUS_M]
            if len(near) > per_frame:
                near = near[np.sort(rng.choice(len(near), per_frame, replace=False))]
            scans.append(
                PointSet(
                    f"scan-{int(frame):06d}",
                    1000 * near,
                    _height_colours(near[:, 2]),
                    shown_at_s=float(times_s[k]),
                    extras={"frame": int(frame)},
                )
            )
        labelled = _labelled_box(sequence, tracklets, document.get("track_id"), frames)
    tracked = MovingBox(
        "tracked-box",
        tuple(1000 * check_boxes(boxes)[0, 3:6]),
        times_s,
        1000 * boxes[:, :3],
        boxes[:, 6],
        (1.0, 0.85, 0.0, 1.0),
        {"confidence": [f["confidence"] for f in document["frames"]]},
    )
    moving = [tracked]
    if labelled is not None:
        keep = np.isfinite(labelled).all(axis=1)
        truth = labelled[keep]
        moving.append(
            MovingBox(
                "true-box",
                tuple(1000 * truth[0, 3:6]),
                times_s[keep],
                1000 * truth[:, :3],
                truth[:, 6],
                (0.2, 0.9, 0.3, 1.0),
                {"frames": [int(f) for f in np.asarray(frames)[keep]]},
            )
        )
    figures = {k: v for k, v in files.result.items() if not isinstance(v, dict)}
    return JobScene(
        points=tuple(scans),
        boxes=tuple(moving),
        frame_s=frame_s,
        frame="each scan's LiDAR frame (x forward, y left, z up)",
        extras={"figures": figures, "frames": [int(f) for f in frames]},
    )


def _labelled_box(sequence, tracklets, track_id, frames: np.ndarray) -> np.ndarray | None:  # noqa: ANN001
    """(F, 7) the labelled box of ``track_id`` at each frame (NaN rows: not labelled), or
    None without labels or a track id."""
    if track_id is None or sequence.labels is None:
        return None
    runs = [
        t
        for t in tracklets(
            sequence, types=("Car", "Van", "Truck", "Pedestrian", "Cyclist"), min_frames=1
        )
        if t.track_id == track_id
    ]
    boxes = np.full((len(frames), 7), np.nan)
    for run in runs:
        at = {f: b for f, b in zip(run.frames, run.boxes, strict=True)}
        for k, frame in enumerate(frames):
            if int(frame) in at:
                boxes[k] = at[int(frame)]
    return boxes if np.isfinite(boxes).all(axis=1).any() else None


def _height_colours(z_m: np.ndarray) -> np.ndarray:
    """Viridis by height from 2 m below the sensor to 1 m above it."""
    at = np.clip((z_m + 2.0) / 3.0, 0, 1) * (len(HEIGHT_COLOURS) - 1)
    return np.column_stack(
        [np.interp(at, np.arange(len(HEIGHT_COLOURS)), HEIGHT_COLOURS[:, c]) for c in range(3)]
    ).astype(np.uint8)
