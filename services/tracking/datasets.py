"""Labelled LiDAR data for training and checking, from the folders users have:

- sequences (any layout of ``sequence``: vista's simulations, a KITTI tracking download's
  ``training/velodyne/NNNN``, a drive labelled in the object format);
- KITTI object-benchmark folders: ``velodyne/``, ``calib/`` and ``label_2/`` with one file
  a scan.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from services.lib import kitti
from services.tracking.sequence import open_sequence

NEIGHBOURS = ("Van", "Truck")


@dataclass(frozen=True)
class LabelledScan:
    path: Path
    calibration: kitti.Calibration
    labels: kitti.Labels
    """The scan's label rows (cars, their neighbours, DontCare regions …)."""
    group: str
    """The sequence (or folder) it comes from: a split keeps a group's neighbours together."""

    @cached_property
    def cars(self) -> np.ndarray:
        """(N, 7) the scan's cars (KITTI's Car), LiDAR boxes."""
        return kitti.camera_to_lidar(self.labels.of_type("Car").camera_box, self.calibration)

    @cached_property
    def ignored(self) -> np.ndarray:
        """(M, 7) vans and trucks: a detector is neither rewarded nor punished there."""
        return kitti.camera_to_lidar(self.labels.of_type(*NEIGHBOURS).camera_box, self.calibration)

    @cached_property
    def objects(self) -> np.ndarray:
        """(K, 7) every labelled object's LiDAR box (cars, vans, people, cyclists, misc)."""
        rows = np.asarray(self.labels.type, dtype=object) != kitti.DONT_CARE
        return kitti.camera_to_lidar(self.labels.select(rows).camera_box, self.calibration)

    @cached_property
    def dont_care(self) -> np.ndarray:
        """(K, 4) image regions the annotators left unlabelled (left, top, right, bottom)."""
        return self.labels.of_type(kitti.DONT_CARE).bbox

    @property
    def name(self) -> str:
        return f"{Path(self.group).name}/{self.path.stem}"


def _object_folder(folder: Path) -> list[LabelledScan]:
    out = []
    for label in sorted((folder / "label_2").glob("*.txt")):
        scan = folder / "velodyne" / f"{label.stem}.bin"
        calib = folder / "calib" / f"{label.stem}.txt"
        if scan.exists() and calib.exists():
            calibration = kitti.read_calibration(calib)
            out.append(
                LabelledScan(scan, calibration, kitti.read_object_labels(label), str(folder))
            )
    return out


def labelled_scans(folders: list[Path], frame_step: int = 1) -> list[LabelledScan]:
    """Every labelled scan of ``folders`` (a sequence's every ``frame_step``-th labelled
    frame); ValueError naming a folder without labels."""
    out: list[LabelledScan] = []
    for folder in map(Path, folders):
        if (folder / "label_2").is_dir() and (folder / "calib").is_dir():
            found = _object_folder(folder)
            if not found:
                raise ValueError(
                    f"{folder}: label_2/ has no scan with its velodyne/ .bin and calib/ file"
                )
            out += found
            continue
        sequence = open_sequence(folder)
        if sequence.labels is None:
            raise ValueError(
                f"{folder}: a sequence without labels (label_02.txt or label_2/): nothing to learn from"
            )
        labels = sequence.labels
        labelled = [f for f in sequence.frames if (labels.frame == f).any()]
        for frame in labelled[::frame_step]:
            out.append(
                LabelledScan(
                    sequence.scans[frame],
                    sequence.calibration,
                    labels.select(labels.frame == frame),
                    str(folder),
                )
            )
    return out


def split_groups(
    items: list, groups: list[str], val_fraction: float, seed: int, block: int = 20
) -> tuple[np.ndarray, np.ndarray]:
    """Indices for training and validation: runs of ``block`` consecutive items of one group
    go to the same side (neighbouring frames of a drive look alike)."""
    keys = []
    previous, run, count = None, 0, 0
    for group in groups:
        if group != previous or count == block:
            run, count = run + 1, 0
        previous, count = group, count + 1
        keys.append(run)
    keys = np.array(keys)
    runs = np.unique(keys)
    chosen = np.random.default_rng(seed).permutation(runs)[
        : max(1, int(round(len(runs) * val_fraction)))
    ]
    val = np.isin(keys, chosen) if len(runs) > 1 else np.zeros(len(items), bool)
    if len(runs) == 1 and len(items) > 1:
        val[-max(1, int(round(len(items) * val_fraction))) :] = True
    return np.flatnonzero(~val), np.flatnonzero(val)


def data_fingerprint(paths: list[Path]) -> str:
    digest = hashlib.sha256()
    for path in paths:
        digest.update(str(path).encode())
        digest.update(str(path.stat().st_size).encode())
    return digest.hexdigest()
