"""Small tracking-service files for tests: a short simulated LiDAR drive, packed as the
`lidar` artifact takes it."""

from __future__ import annotations

import tarfile
from pathlib import Path

REAL_OBJECTS = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti-object-sample"
REAL_DRIVE = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti-raw-2011_09_26"
REAL_LABELLED_DRIVE = REAL_DRIVE.with_name("kitti-raw-2011_09_26_drive_0048")


def small_drive(folder: Path, *, frames: int = 12, cars: int = 3, seed: int = 3) -> Path:
    """A short simulated drive (the ego car behind track 0 all the way)."""
    from services.tracking.simulate import simulate_sequence

    simulate_sequence(folder, frames=frames, cars=cars, seed=seed)
    return folder


def pack_sequence(folder: Path, out: Path, *, labels: bool = True) -> Path:
    """``folder``'s velodyne/, calib.txt, poses.txt (and label_02.txt) as a tar.gz under a top
    folder named like the sequence."""
    names = ["calib.txt", "poses.txt", *(["label_02.txt"] if labels else [])]
    with tarfile.open(out, "w:gz") as archive:
        for path in sorted((folder / "velodyne").glob("*.bin")):
            archive.add(path, arcname=f"{folder.name}/velodyne/{path.name}")
        for name in names:
            archive.add(folder / name, arcname=f"{folder.name}/{name}")
    return out
