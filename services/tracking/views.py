"""What a tracking run's page shows: the confidence over the frames with the detector's runs
and the resets marked, the box's path seen from above, and the run's figures
(``contract.views``); and its 3D scene, the scans with the box moving through them
(``contract.scene``). A detection run's: the camera images with their boxes, the cars and
scores per scan, the recall and precision; its scene, each scan with its boxes."""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from contract.scene import JobScene, MovingBox, PointSet
from contract.views import Figure, Figures, JobFiles, Line, Picture, Pictures, Plot
from services.tracking.kinds import DETECTIONS, DETECTIONS_IMAGE, EVALUATION, TRACK_REPORT


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
DETECTION_RADIUS_M = 60.0
"""A detection run's scans are kept this far around the sensor."""
FRAME_S = 0.1
"""KITTI's LiDAR turns at 10 Hz."""
LIDAR_FRAME = "each scan's LiDAR frame (x forward, y left, z up)"
HEIGHT_COLOURS = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]]
)
"""Viridis at five heights, low to high."""


def track_scene(files: JobFiles, max_points: int) -> JobScene:
    """The drive as the tracker saw it: each frame's scan within ``SCENE_RADIUS_M`` of the
    box (coloured by height; the point budget shared among the frames), shown for its frame,
    and the tracked box moving one key a frame — with the labelled box when the drive had
    labels for the track. In each scan's own LiDAR frame (x forward, y left, z up)."""
    from services.lib.boxes import check_boxes
    from services.tracking.report import lidar_boxes
    from services.tracking.sequence import tracklets

    document = files.json(TRACK_REPORT.file_name())
    if document is None:
        raise ValueError("the run wrote no track.json")
    frames, boxes = lidar_boxes(document)
    per_frame = max(100, max_points // len(frames))
    times_s = np.arange(len(frames)) * FRAME_S
    rng = np.random.default_rng(0)
    with _opened_sequence(files) as sequence:
        scans = []
        for k, (frame, box) in enumerate(zip(frames, boxes, strict=True)):
            points = sequence.points(int(frame))[:, :3]
            near = np.hypot(*(points[:, :2] - box[:2]).T) <= SCENE_RADIUS_M
            scans.append(_scan(points[near], int(frame), float(times_s[k]), per_frame, rng))
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
    return _drive_scene(files, scans, moving, [int(f) for f in frames])


def _drive_scene(
    files: JobFiles, scans: list[PointSet], boxes: list[MovingBox], frames: list[int]
) -> JobScene:
    """A drive's scene: its scans and boxes frame by frame in the LiDAR frame, the run's
    figures in its extras."""
    figures = {k: v for k, v in files.result.items() if not isinstance(v, dict)}
    return JobScene(
        points=tuple(scans),
        boxes=tuple(boxes),
        frame_s=FRAME_S,
        frame=LIDAR_FRAME,
        extras={"figures": figures, "frames": frames, "legend": _legend(boxes)},
    )


BOX_WORDS = {
    "tracked-box": "the tracked car (the tracker's box)",
    "true-box": "the labelled car (ground truth)",
}


def _legend(boxes: list[MovingBox]) -> list[dict]:
    """What every colour of a drive's scene means: the scans' height scale, and each box
    colour drawn (a detection's by its verdict)."""
    legend = [
        {
            "gradient": [_hex(c) for c in HEIGHT_COLOURS],
            "text": "scan points by height: 2 m below the sensor → 1 m above",
        }
    ]
    said = set()
    for box in boxes:
        verdict = box.extras.get("verdict") or ("missed" if box.name.startswith("missed") else None)
        text = BOX_WORDS.get(box.name) or VERDICT_WORDS.get(verdict or "", box.name)
        if text in said:
            continue
        said.add(text)
        colour = tuple(round(255 * c) for c in box.colour_rgba[:3])
        legend.append({"colour": _hex(colour), "text": text})
    return legend


@contextmanager
def _opened_sequence(files: JobFiles) -> Iterator:
    """The run's `lidar` input unpacked and opened (a ``Sequence``), for the block."""
    from services.tracking.lidar_archive import extract_lidar
    from services.tracking.sequence import open_sequence

    archives = list(files.inputs_of_kind("lidar").values())
    if len(archives) != 1:
        raise ValueError("the run's LiDAR sequence is not among its inputs")
    with tempfile.TemporaryDirectory(prefix="vista-lidar-scene-") as folder:
        extract_lidar(archives[0], Path(folder))
        yield open_sequence(Path(folder))


def _scan(
    points_m: np.ndarray, frame: int, shown_at_s: float, most: int, rng: np.random.Generator
) -> PointSet:
    """One frame's scan (at most ``most`` of its points, drawn at random) coloured by height."""
    if len(points_m) > most:
        points_m = points_m[np.sort(rng.choice(len(points_m), most, replace=False))]
    return PointSet(
        f"scan-{frame:06d}",
        1000 * points_m,
        _height_colours(points_m[:, 2]),
        shown_at_s=shown_at_s,
        extras={"frame": frame},
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


DRAWN = "detections (green: found, red: false, amber: not judged, grey: missed)"
VERDICT_WORDS = {
    "found": "found a labelled car",
    "false": "no car there (false)",
    "unjudged": "not judged",
    "missed": "labelled car missed",
}


def detect_view(files: JobFiles) -> list:
    from services.tracking.detect import BOX_COLOURS_RGB, box_verdicts

    document = files.json(DETECTIONS.file_name()) or {}
    scans = document.get("scans", [])
    frames = [float(scan["frame"]) for scan in scans]
    images = {
        int(Path(name).stem): Path(name) for name in files.inputs_of_kind("image")
        if Path(name).stem.isdigit()
    }  # fmt: skip
    pictures = [
        Picture(
            f"scan {images[scan['frame']].stem}: {len(scan['scores'])} cars",
            [
                DETECTIONS_IMAGE.file_name(images[scan["frame"]].stem),
                f"image/{images[scan['frame']]}",
            ],
            [DRAWN, "camera image"],
        )
        for scan in scans
        if scan["frame"] in images
    ]
    counts = [Line("cars detected", frames, [float(len(s["scores"])) for s in scans])]
    scored = [s for s in scans if s.get("scored")]
    if scored:
        at = [float(s["frame"]) for s in scored]
        near = f"{document['near_m']:.0f} m"
        counts += [
            Line(
                f"labelled cars within {near}",
                at,
                [float(s["cars_near"]) for s in scored],
                colour=_hex(BOX_COLOURS_RGB["missed"]),
            ),
            Line(
                "of them found",
                at,
                [float(s["found_near"]) for s in scored],
                colour=_hex(BOX_COLOURS_RGB["found"]),
            ),
        ]
    verdicts = [
        (s["frame"], score, v)
        for s in scans
        for score, v in zip(s["scores"], box_verdicts(s), strict=True)
    ]
    scores = [
        Line(
            VERDICT_WORDS[verdict],
            [float(f) for f, _, v in verdicts if v == verdict],
            [float(score) for _, score, v in verdicts if v == verdict],
            style="points",
            colour=_hex(BOX_COLOURS_RGB[verdict]),
        )
        for verdict in ("found", "false", "unjudged")
        if any(v == verdict for _, _, v in verdicts)
    ]
    panels: list = [Pictures("Camera images", pictures)] if pictures else []
    panels.append(Plot("Cars per scan", "frame", "cars", counts))
    if scores:
        panels.append(Plot("Scores", "frame", "score", scores))
    return panels + [Figures("Detection", _detection_figures(document))]


def _hex(rgb: tuple[int, int, int]) -> str:
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def _detection_figures(document: dict) -> list[Figure]:
    scans = document.get("scans", [])
    found = sum(len(s["scores"]) for s in scans)
    figures = [
        Figure("detector", document.get("detector")),
        Figure(
            "model",
            (document.get("model") or "vista's shipped model")
            if document.get("detector") == "learned"
            else "none",
        ),
        Figure("score threshold", document.get("threshold")),
        Figure("scans", len(scans)),
        Figure("cars detected", found),
        Figure("in the camera's view", sum(sum(s["in_view"]) for s in scans)),
        Figure("time a scan", document.get("ms_per_scan"), "ms"),
    ]
    evaluation = document.get("evaluation")
    if evaluation is None:
        why = "the sequence has no labels (label_02.txt)"
        return figures + [Figure("recall / precision", None, note=why)]
    judged = evaluation["true_positives"] + evaluation["false_positives"]
    return figures + [
        Figure("scans with labels", evaluation["scans"]),
        _ratio(
            f"recall within {evaluation['near_m']:.0f} m",
            evaluation["found_near"],
            evaluation["cars_near"],
        ),
        _ratio("precision in the camera's view", evaluation["true_positives"], judged),
    ]


def _ratio(label: str, hits: int, total: int) -> Figure:
    """hits/total with its 95 % interval (``ratio_text``), or unmeasured with nothing to count."""
    from services.tracking.detection_eval import ratio_text

    if not total:
        return Figure(label, None, note="nothing to count")
    return Figure(label, ratio_text(hits, total))


def detect_scene(files: JobFiles, max_points: int) -> JobScene:
    """Each scan within ``DETECTION_RADIUS_M`` of the sensor (coloured by height; the point
    budget shared among them) shown for its frame, with its boxes: each detection coloured
    by its verdict (scores in its extras), and the labelled cars it missed in grey."""
    from services.tracking.detect import BOX_COLOURS_RGB, box_verdicts

    document = files.json(DETECTIONS.file_name())
    if document is None:
        raise ValueError("the run wrote no detections.json")
    scans = document["scans"]
    per_frame = max(100, max_points // max(len(scans), 1))
    rng = np.random.default_rng(0)
    points, boxes = [], []
    with _opened_sequence(files) as sequence:
        for k, scan in enumerate(scans):
            frame, shown_at_s = int(scan["frame"]), k * FRAME_S
            cloud = sequence.points(frame)[:, :3]
            near = np.hypot(cloud[:, 0], cloud[:, 1]) <= DETECTION_RADIUS_M
            points.append(_scan(cloud[near], frame, shown_at_s, per_frame, rng))
            drawn = [
                (f"detection-{frame:06d}-{n}", box, verdict, {"score": score})
                for n, (box, score, verdict) in enumerate(
                    zip(scan["boxes"], scan["scores"], box_verdicts(scan), strict=True)
                )
            ] + [
                (f"missed-{frame:06d}-{n}", box, "missed", {})
                for n, box in enumerate(scan.get("missed", []))
            ]
            boxes += [
                MovingBox(
                    name,
                    tuple(1000 * np.asarray(box[3:6])),
                    np.zeros(1),
                    1000 * np.asarray([box[:3]]),
                    np.asarray([box[6]]),
                    (*(c / 255 for c in BOX_COLOURS_RGB[verdict]), 1.0),
                    {"frame": frame, "verdict": verdict, **about},
                    shown_at_s=shown_at_s,
                )
                for name, box, verdict, about in drawn
            ]
    return _drive_scene(files, points, boxes, [int(s["frame"]) for s in scans])
