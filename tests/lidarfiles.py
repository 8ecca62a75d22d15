"""Small tracking-service files for tests: a short simulated LiDAR drive, packed as the
`lidar` artifact takes it."""

from __future__ import annotations

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
    """``folder`` as the `lidar` archive (``services.tracking.lidar_archive``)."""
    from services.tracking.lidar_archive import write_lidar_archive

    return write_lidar_archive(folder, out, labels=labels)
