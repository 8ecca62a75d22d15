"""One tracking run from a sequence folder (what ``vista tracking track`` and the
``tracking.track`` job do), and the evaluation of runs against a sequence's labels
(``vista tracking eval``)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.lib import kitti
from services.lib.boxes import check_boxes, iou_3d
from services.tracking.kinds import DETECTORS, TRACKERS, TrackParams
from services.tracking.ope import OPEResult, frame_scores, one_pass
from services.tracking.pipeline import Detector, track
from services.tracking.report import lidar_boxes, track_document
from services.tracking.resets import ResetPolicy
from services.tracking.sequence import Sequence, open_sequence, tracklets
from services.tracking.tracker import Tracker


def make_tracker(name: str, model: Path | None, threads: int = 1) -> Tracker:
    from services.tracking.geometric_tracker import GeometricTracker

    if name == "geometric":
        return GeometricTracker()
    if name == "siamese":
        if model is None:
            raise ValueError(
                "the siamese tracker needs its encoder: --siamese-model SIAMESE.onnx (build one with "
                "`vista tracking train DATA… --network siamese -o SIAMESE.onnx`)"
            )
        from services.tracking.siamese import SiameseTracker

        return SiameseTracker(model, threads=threads)
    raise ValueError(f"tracker {name!r}: known trackers are {', '.join(TRACKERS)}")


def make_detector(name: str, model: Path | None, threads: int = 1) -> Detector:
    if name == "geometric":
        from services.tracking.detect_geometric import GeometricDetector

        return GeometricDetector()
    if name == "learned":
        from services.tracking.detect_learned import DEFAULT_MODEL, LearnedDetector

        if model is None and not DEFAULT_MODEL.is_file():
            raise ValueError(
                f"this installation lacks vista's shipped detector ({DEFAULT_MODEL}): give "
                "--detector-model DETECTOR.onnx (build one with `vista tracking train`) "
                "or use --detector geometric"
            )
        if model is not None and not Path(model).is_file():
            raise ValueError(f"--detector-model {model}: no such model file")
        return LearnedDetector(model or DEFAULT_MODEL, threads=threads)
    raise ValueError(f"detector {name!r}: known detectors are {', '.join(DETECTORS)}")


@dataclass(frozen=True)
class Target:
    frames: list[int]
    box: np.ndarray
    """(7,) the target's LiDAR box in the first frame."""
    track_id: int | None


def parse_camera_box(text: str) -> np.ndarray:
    """``"h w l x y z ry"`` (KITTI's camera box, metres and radians) → (7,)."""
    try:
        values = np.array(text.replace(",", " ").split(), dtype=np.float64)
    except ValueError:
        values = np.zeros(0)
    if values.shape != (7,) or not np.isfinite(values).all() or (values[:3] <= 0).any():
        raise ValueError(
            f"--init-box {text!r}: give seven numbers 'h w l x y z ry' (KITTI's camera box: "
            "positive height, width and length in metres, the bottom centre, rotation_y in radians)"
        )
    return values


def find_target(
    sequence: Sequence,
    *,
    track_id: int | None = None,
    init_box: np.ndarray | None = None,
    start_frame: int | None = None,
    end_frame: int | None = None,
) -> Target:
    """The frames to track and the first box: a labelled track's first run of consecutive
    frames, or a box (KITTI camera frame) given in ``start_frame`` (default the first) up
    to ``end_frame`` (default the last)."""
    if (track_id is None) == (init_box is None):
        raise ValueError("give the target either by track_id (a labelled track) or by init_box")
    if track_id is not None:
        if sequence.labels is None:
            raise ValueError(
                f"{sequence.folder}: no labels (label_02.txt or label_2/), so there is no track "
                "to follow by track_id: give the car's box as init_box"
            )
        runs = [
            t
            for t in tracklets(sequence, tuple(sorted(set(sequence.labels.type))), min_frames=1)
            if t.track_id == track_id
        ]
        if not runs:
            known = sorted(set(int(i) for i in sequence.labels.track_id))
            raise ValueError(
                f"track {track_id} is not in {sequence.folder}'s labels (tracks: {known[:20]}{'…' if len(known) > 20 else ''})"
            )
        run = runs[0]
        frames = [f for f in run.frames if f in sequence.scans]
        if len(frames) != len(run.frames):
            raise ValueError(
                f"track {track_id}: {len(run.frames) - len(frames)} of its frames have no scan"
            )
        return Target(frames, run.boxes[0], track_id)
    frames = sequence.frames
    first = frames[0] if start_frame is None else start_frame
    last = frames[-1] if end_frame is None else end_frame
    if first not in sequence.scans:
        raise ValueError(f"--start-frame {first}: no such scan (frames {frames[0]}–{frames[-1]})")
    chosen = [f for f in frames if first <= f <= last]
    box = kitti.camera_to_lidar(init_box[None], sequence.calibration)[0]
    return Target(chosen, check_boxes(box, "the initial box"), None)


def scan_stream(
    sequence: Sequence, frames: list[int], scans: dict[int, np.ndarray] | None = None
) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
    """(frame, points, ego motion since the previous frame) in order: the motion from the
    sequence's poses, or estimated from the scans when it has none (``egomotion``); the
    points from ``scans`` when given (read once), else from disk."""
    from services.tracking.egomotion import EgoMotion

    estimate = EgoMotion() if sequence.poses is None else None
    previous = None
    for frame in frames:
        points = scans[frame] if scans is not None else sequence.points(frame)
        if estimate is not None:
            motion = estimate(points)
        else:
            motion = None if previous is None else sequence.ego_motion(previous, frame)
        yield frame, points, motion
        previous = frame


def run_tracking(
    folder: Path,
    params: TrackParams,
    *,
    siamese_model: Path | None = None,
    detector_model: Path | None = None,
    threads: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Track the target ``params`` give through the sequence in ``folder``, with their
    tracker, detector and reset policy (the models: the Siamese encoder, a learned detector
    instead of the shipped one); the TRACK.json document."""
    policy = ResetPolicy.parse(params.reset)
    sequence = open_sequence(folder)
    target = find_target(
        sequence,
        track_id=params.track_id,
        init_box=None if params.init_box is None else np.array(params.init_box),
        start_frame=params.start_frame,
        end_frame=params.end_frame,
    )
    the_tracker = make_tracker(params.tracker, siamese_model, threads)
    the_detector = (
        make_detector(params.detector, detector_model, threads) if policy.mode != "never" else None
    )
    result = track(
        scan_stream(sequence, target.frames),
        target.box,
        the_tracker,
        the_detector,
        policy,
        progress=progress,
        total=len(target.frames) - 1,
    )
    return track_document(
        result,
        sequence.calibration,
        sequence=str(folder),
        track_id=target.track_id,
        tracker=params.tracker,
        detector=params.detector if policy.mode != "never" else None,
        reset=policy.text(),
        ego_motion=sequence.poses is not None,
    )


@dataclass(frozen=True)
class Evaluation:
    pooled: OPEResult
    runs: list[dict]

    def document(self) -> dict:
        return {"ope": self.pooled.document(), "runs": self.runs}


def evaluate_runs(folder: Path, documents: list[tuple[str, dict]]) -> Evaluation:
    """One-Pass Evaluation of TRACK.json documents (name, document) against the sequence's
    labels: each run is matched to its track (its ``track_id``, or the labelled box its first
    box overlaps most), frames the label lacks are left out and counted."""
    sequence = open_sequence(folder)
    if sequence.labels is None:
        raise ValueError(f"{folder}: no labels (label_02.txt) to evaluate against")
    labels = sequence.labels
    truth_boxes = kitti.camera_to_lidar(labels.camera_box, sequence.calibration)
    overlaps, errors, runs = [], [], []
    for name, document in documents:
        frames, boxes = lidar_boxes(document)
        track_id = document.get("track_id")
        if track_id is None:
            first = labels.frame == frames[0]
            if not first.any():
                raise ValueError(
                    f"{name}: no labelled object in its first frame {frames[0]} to match it to"
                )
            ious = iou_3d(truth_boxes[first], boxes[0][None])
            if ious.max() < 0.3:
                raise ValueError(
                    f"{name}: its first box overlaps no labelled object (best 3D IoU {ious.max():.2f})"
                )
            track_id = int(labels.track_id[first][int(ious.argmax())])
        rows = {
            int(f): i
            for i, f in zip(
                np.flatnonzero(labels.track_id == track_id),
                labels.frame[labels.track_id == track_id],
                strict=True,
            )
        }
        keep = [k for k, f in enumerate(frames) if f in rows]
        if not keep:
            raise ValueError(f"{name}: track {track_id} has no label in the run's frames")
        truth = truth_boxes[[rows[frames[k]] for k in keep]]
        iou, error = frame_scores(boxes[keep], truth)
        overlaps.append(iou)
        errors.append(error)
        scores = one_pass([iou], [error])
        runs.append(
            {
                "name": name,
                "track_id": track_id,
                "frames": len(keep),
                "unlabelled_frames": len(frames) - len(keep),
                "success": round(scores.success, 3),
                "precision": round(scores.precision, 3),
                "detector_cost_percent": document.get("detector_cost_percent"),
                "fps": document.get("fps"),
            }
        )
    return Evaluation(one_pass(overlaps, errors), runs)
