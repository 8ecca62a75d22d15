"""A LiDAR sequence on disk, in any of the layouts users have:

- vista's (``vista tracking simulate`` writes it): ``SEQ/velodyne/*.bin``, ``SEQ/calib.txt``,
  and as known ``SEQ/label_02.txt`` and ``SEQ/poses.txt``;
- a KITTI tracking download as it unpacks: ``SEQ_DIR`` is ``…/training/velodyne/0011``,
  its calibration ``…/training/calib/0011.txt``, its labels ``…/training/label_02/0011.txt``;
- a KITTI raw drive: ``velodyne_points/data/*.bin`` with the date folder's
  ``calib_cam_to_cam.txt`` and ``calib_velo_to_cam.txt``, or vista's shared sample
  (``velodyne/`` with ``calib.json``);
- a drive labelled in the object benchmark's format: ``velodyne/``, ``calib.txt`` and
  ``label_2/NNNNNNNNNN.txt`` for the labelled frames (every other one, say). Such labels
  have no track ids: an object keeps its exact type and ``h w l`` from frame to frame, which
  links it (two alike in one frame are told apart by where they stand).

Frames are numbered by their file names (``000042.bin`` is frame 42), as labels refer to
them.

Tracklets are the single-object benchmarks' (SC3D, P2B): one per labelled object and run
of consecutive frames it is labelled in — consecutive in the sequence's labelling step, so
a drive labelled every other frame gives tracklets through every frame, with the boxes of
the unlabelled ones unknown (NaN) and left out of the evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.lib import kitti


@dataclass(frozen=True)
class Sequence:
    folder: Path
    scans: dict[int, Path]
    """Frame number → its ``.bin`` file."""
    calibration: kitti.Calibration
    labels: kitti.Labels | None
    poses: np.ndarray | None
    """(F, 4, 4) ``velo0_T_veloi`` per frame in file order (from ``poses.txt``), or None."""
    label_step: int = 1
    """Frames between two labelled ones (1: every frame is labelled)."""

    @property
    def frames(self) -> list[int]:
        return sorted(self.scans)

    def points(self, frame: int) -> np.ndarray:
        return kitti.read_velodyne(self.scans[frame])

    def ego_motion(self, previous: int, frame: int) -> np.ndarray | None:
        """``prev_T_cur`` (4 × 4): the current scan's frame in the previous one's, from the
        poses; None without poses."""
        if self.poses is None:
            return None
        order = {f: i for i, f in enumerate(self.frames)}
        return np.linalg.inv(self.poses[order[previous]]) @ self.poses[order[frame]]


@dataclass(frozen=True)
class Tracklet:
    track_id: int
    type: str
    frames: list[int]
    boxes: np.ndarray
    """(F, 7) LiDAR boxes, one per frame (NaN rows: frames between labelled ones)."""

    @property
    def labelled(self) -> np.ndarray:
        """(F,) bool: the frames whose box is known."""
        return np.isfinite(self.boxes).all(axis=1)


def _scan_files(folder: Path) -> dict[int, Path]:
    scans = {}
    for path in sorted(folder.glob("*.bin")):
        if path.stem.isdigit():
            scans[int(path.stem)] = path
    return scans


def _first(*candidates: Path) -> Path | None:
    return next((c for c in candidates if c.exists()), None)


def open_sequence(folder: Path) -> Sequence:
    """The sequence in ``folder`` (see the module's layouts); ValueError naming what is
    missing."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such folder")
    if (folder / "velodyne").is_dir():  # vista's layout, or the shared raw sample
        scan_dir = folder / "velodyne"
        calib = _first(folder / "calib.txt", folder / "calib.json")
        labels = _first(folder / "label_02.txt", folder / "label_2")
        poses = _first(folder / "poses.txt")
    elif folder.parent.name == "velodyne":  # a KITTI tracking download
        root, name = folder.parent.parent, folder.name
        scan_dir = folder
        calib = _first(root / "calib" / f"{name}.txt")
        labels = _first(root / "label_02" / f"{name}.txt")
        poses = _first(root / "poses" / f"{name}.txt")
    elif (folder / "velodyne_points" / "data").is_dir():  # a KITTI raw drive
        scan_dir = folder / "velodyne_points" / "data"
        calib = _first(folder.parent / "calib_cam_to_cam.txt", folder / "calib_cam_to_cam.txt")
        labels, poses = None, _first(folder / "poses.txt")
    else:
        raise ValueError(
            f"{folder}: not a LiDAR sequence (velodyne/*.bin with calib.txt, a KITTI tracking "
            "download's training/velodyne/NNNN, or a raw drive with velodyne_points/data)"
        )
    scans = _scan_files(scan_dir)
    if not scans:
        raise ValueError(f"{scan_dir}: no scans (NNNNNN.bin, float32 x y z reflectance)")
    if calib is None:
        raise ValueError(
            f"{folder}: no calibration (calib.txt, calib/NNNN.txt or calib.json) was found"
        )
    calibration = kitti.read_calibration(calib)
    if labels is None:
        read_labels = None
    elif labels.is_dir():
        read_labels = linked_object_labels(labels)
    else:
        read_labels = kitti.read_tracking_labels(labels)
    lidar = None
    if poses is not None:
        camera = kitti.read_poses(poses)
        if len(camera) < len(scans):
            raise ValueError(f"{poses}: {len(camera)} poses for {len(scans)} scans")
        lidar = kitti.lidar_poses(camera[: len(scans)], calibration)
    return Sequence(folder, scans, calibration, read_labels, lidar, _label_step(read_labels))


def _label_step(labels: kitti.Labels | None) -> int:
    """The commonest gap between consecutive labelled frames (1 when every frame is)."""
    if labels is None or len(np.unique(labels.frame)) < 2:
        return 1
    gaps = np.diff(np.unique(labels.frame))
    values, counts = np.unique(gaps, return_counts=True)
    return int(values[counts.argmax()])


def linked_object_labels(folder: Path) -> kitti.Labels:
    """Object-format label files ``NNNN.txt`` of one drive's frames as tracking labels (see
    ``link_object_labels``)."""
    files = sorted(p for p in Path(folder).glob("*.txt") if p.stem.isdigit())
    if not files:
        raise ValueError(f"{folder}: no label files (NNNNNNNNNN.txt, KITTI object format)")
    return link_object_labels(
        [kitti.read_object_labels(path).with_frame(int(path.stem)) for path in files]
    )


def link_object_labels(parts: list[kitti.Labels]) -> kitti.Labels:
    """One drive's object-format labels, a part per frame (its frame set), as tracking
    labels: one track id per object — the rows of one type and exact ``h w l`` (KITTI's
    annotators keep an object's size), and where two alike share a frame, each linked to
    the nearer of the previous frame's. DontCare rows keep track id −1."""
    labels = kitti.concatenate_labels(parts)
    track = np.full(len(labels), -1)
    objects = np.flatnonzero(np.asarray(labels.type, dtype=object) != kitti.DONT_CARE)
    keys: dict[tuple, list[tuple[int, np.ndarray]]] = {}  # (type, h, w, l) → [(track, where)]
    next_id = 0
    for frame in np.unique(labels.frame):
        here = objects[labels.frame[objects] == frame]
        for row in here:
            key = (labels.type[row], *np.round(labels.camera_box[row, :3], 2))
            position = labels.camera_box[row, 3:6]
            tracks = keys.setdefault(key, [])
            taken = set(track[here])
            free = [(i, (t, p)) for i, (t, p) in enumerate(tracks) if t not in taken]
            if free:
                slot, (track_id, _) = min(free, key=lambda f: np.linalg.norm(f[1][1] - position))
                tracks[slot] = (track_id, position)
            else:
                track_id, next_id = next_id, next_id + 1
                tracks.append((track_id, position))
            track[row] = track_id
    return labels.with_track_ids(track)


def tracklets(
    sequence: Sequence, types: tuple[str, ...] = ("Car",), min_frames: int = 2
) -> list[Tracklet]:
    """Every labelled object's runs of frames labelled one ``label_step`` apart (of at least
    ``min_frames`` labelled frames), through every frame between them."""
    if sequence.labels is None:
        raise ValueError(f"{sequence.folder}: no labels (label_02.txt) to take tracklets from")
    labels = sequence.labels.of_type(*types)
    boxes = kitti.camera_to_lidar(labels.camera_box, sequence.calibration)
    step = sequence.label_step
    out = []
    for track in np.unique(labels.track_id[labels.track_id >= 0]):
        rows = np.flatnonzero(labels.track_id == track)
        rows = rows[np.argsort(labels.frame[rows], kind="stable")]
        frames = labels.frame[rows]
        breaks = np.flatnonzero(np.diff(frames) != step) + 1
        for run in np.split(np.arange(len(rows)), breaks):
            if len(run) < min_frames:
                continue
            labelled = frames[run]
            scanned = [f for f in sequence.frames if labelled[0] <= f <= labelled[-1]]
            every = sorted(set(scanned) | set(labelled.tolist()))
            run_boxes = np.full((len(every), 7), np.nan)
            run_boxes[np.searchsorted(every, labelled)] = boxes[rows[run]]
            out.append(
                Tracklet(int(track), labels.type[rows[run[0]]], [int(f) for f in every], run_boxes)
            )
    return out
