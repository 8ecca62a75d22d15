"""The tracking service's sample run (``contract.samples``): a simulated LiDAR drive with
labels, track 0 followed through it and its cars detected; and in the real data, as it
holds them, a KITTI raw drive with per-frame labels (velodyne/, label_2/, calib.txt) — a
car followed through its real scans, its cars detected and judged — and a drive with its
camera images (velodyne/, image_02/, calib.json or calib.txt): its cars detected and drawn
on the images."""

from __future__ import annotations

from pathlib import Path

from contract.samples import SampleRun, SampleStep, Upload
from services.lib import kitti
from services.tracking.lidar_archive import write_lidar_archive
from services.tracking.sequence import linked_object_labels, open_sequence, tracklets
from services.tracking.simulate import simulate_sequence


def sample_run(work: Path, frames: int, real_data: Path | None = None) -> SampleRun:
    folder = work / "drive"
    simulate_sequence(folder, frames=frames, cars=3, seed=3)
    uploads = {
        "drive": Upload(
            write_lidar_archive(folder, work / "drive.tar.gz"), "lidar", "application/gzip"
        )
    }
    steps = [
        SampleStep("track", "tracking.track", ("drive",), {"track_id": 0}),
        SampleStep("detect", "tracking.detect", ("drive",)),
    ]
    about = f"a simulated LiDAR drive of {frames} frames (3 cars, labelled)"
    real = _real_drive(real_data) if real_data is not None else None
    if real is not None:
        archive, track_id, scans = packed_real_drive(real, work / "real-drive")
        uploads["real-drive"] = Upload(archive, "lidar", "application/gzip")
        steps += [
            SampleStep("real-track", "tracking.track", ("real-drive",), {"track_id": track_id}),
            SampleStep("real-detect", "tracking.detect", ("real-drive",)),
        ]
        about += f"; {real.name}: {scans} real scans, the longest labelled car followed, the cars detected"
    camera = _camera_drive(real_data) if real_data is not None else None
    if camera is not None:
        scans = min(frames, CAMERA_SCANS)
        archive, images = packed_camera_drive(camera, work / "camera-drive", scans)
        uploads["camera-drive"] = Upload(archive, "lidar", "application/gzip")
        for image in images:
            uploads[f"camera-{image.stem}"] = Upload(image, "image", "image/png")
        steps.append(
            SampleStep(
                "camera-detect",
                "tracking.detect",
                ("camera-drive", *(f"camera-{image.stem}" for image in images)),
            )
        )
        about += f"; {camera.name}: the cars of {scans} real scans drawn on their camera images"
    return SampleRun(uploads, tuple(steps), about)


CAMERA_SCANS = 6
"""The scans (with their images) of a camera drive the sample detects in."""


def _real_drive(data: Path) -> Path | None:
    """The first KITTI raw drive with per-frame labels under ``data``."""
    found = sorted(
        p.parent
        for p in data.glob("*/label_2")
        if (p.parent / "velodyne").is_dir() and (p.parent / "calib.txt").is_file()
    )
    return found[0] if found else None


def _camera_drive(data: Path) -> Path | None:
    """The first drive with camera 2's images beside its scans under ``data``."""
    found = sorted(
        p.parent
        for p in data.glob("*/image_02")
        if (p.parent / "velodyne").is_dir()
        and any((p.parent / name).is_file() for name in ("calib.txt", "calib.json"))
    )
    return found[0] if found else None


def packed_camera_drive(drive: Path, folder: Path, scans: int) -> tuple[Path, list[Path]]:
    """The first ``scans`` scans of ``drive`` as a `lidar` archive (its calibration as
    calib.txt) and their camera images (named as the scans)."""
    (folder / "velodyne").mkdir(parents=True, exist_ok=True)
    (folder / "images").mkdir(exist_ok=True)
    images = []
    for scan in sorted((drive / "velodyne").glob("*.bin"))[:scans]:
        image = drive / "image_02" / f"{scan.stem}.png"
        if not image.is_file():
            continue
        (folder / "velodyne" / scan.name).write_bytes(scan.read_bytes())
        images.append(folder / "images" / image.name)
        images[-1].write_bytes(image.read_bytes())
    calib = next(drive / n for n in ("calib.txt", "calib.json") if (drive / n).is_file())
    kitti.write_calibration(folder / "calib.txt", kitti.read_calibration(calib))
    return write_lidar_archive(folder, folder.with_suffix(".tar.gz")), images


def packed_real_drive(drive: Path, folder: Path) -> tuple[Path, int, int]:
    """``drive`` as a `lidar` archive (its labels linked into tracks), the track id of its
    longest labelled car and its scan count."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "velodyne").mkdir(exist_ok=True)
    for scan in sorted((drive / "velodyne").glob("*.bin")):
        (folder / "velodyne" / scan.name).write_bytes(scan.read_bytes())
    (folder / "calib.txt").write_bytes((drive / "calib.txt").read_bytes())
    labels = linked_object_labels(drive / "label_2")
    (folder / "label_02.txt").write_text(kitti.format_labels(labels, tracking=True))
    longest = max(tracklets(open_sequence(folder)), key=lambda t: len(t.frames))
    return (
        write_lidar_archive(folder, folder.with_suffix(".tar.gz")),
        longest.track_id,
        len(list((folder / "velodyne").glob("*.bin"))),
    )
