"""A camera drive in KITTI's layout, so users point the depth service at their own folders
(KITTI's file formats themselves are ``services.lib.kitti``'s).

- A *drive* folder holds ``image_02/`` (left colour camera, ``*.png``; KITTI raw's
  ``image_02/data/`` also works), optionally ``image_03/`` (right), ``depth/`` (or the depth
  benchmark's ``proj_depth/groundtruth/image_02/``), ``velodyne/`` (or KITTI raw's
  ``velodyne_points/data/``: LiDAR scans, ``lidar.py``) and ``poses.txt``; its calibration is
  ``calib.json`` (``K`` or ``P_rect_02``, optional ``baseline_m`` or ``P_rect_03``) or
  KITTI's ``calib_cam_to_cam.txt``, in the folder or its parent (raw drives share their
  date folder's).
- ``poses.txt``: one line per frame, the 3 × 4 row-major pose of the left camera in the first
  frame's camera frame (metres): ``cam0_T_cami``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.artifacts import ArtifactRefused, Inspected
from services.depth.camera import KITTI_BASELINE_M, KITTI_HEIGHT, KITTI_WIDTH, PinholeCamera
from services.lib.formats import limit_size, text_of
from services.lib.images import read_image
from services.lib.kitti import read_key_values, read_poses

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
CALIBRATION_FILES = ("calib.json", "calib_cam_to_cam.txt")
MAX_CALIBRATION_BYTES = 1 << 20


def _camera_from(
    projection_2: np.ndarray,
    projection_3: np.ndarray | None,
    size: tuple[int, int],
    baseline_m: float | None,
) -> PinholeCamera:
    P2 = np.asarray(projection_2, dtype=np.float64).reshape(3, 4)
    if baseline_m is None and projection_3 is not None:
        P3 = np.asarray(projection_3, dtype=np.float64).reshape(3, 4)
        baseline_m = float((P2[0, 3] - P3[0, 3]) / P2[0, 0])
    return PinholeCamera(
        size[0], size[1], P2[:, :3], baseline_m if baseline_m else KITTI_BASELINE_M
    )


def read_calibration(folder: Path, size: tuple[int, int]) -> PinholeCamera:
    """The left camera of a drive whose images are ``size`` (width, height): from
    ``calib.json`` or ``calib_cam_to_cam.txt`` in ``folder`` or its parent."""
    for place in (folder, folder.parent):
        for name in CALIBRATION_FILES:
            if (place / name).is_file():
                return read_calibration_file(place / name, size)
    raise ValueError(f"{folder}: no calib.json or calib_cam_to_cam.txt here or in its parent")


def read_calibration_file(path: Path, size: tuple[int, int]) -> PinholeCamera:
    """The left camera from one calibration file, whatever its name: vista's JSON (``K`` or
    ``P_rect_02``, optional ``baseline_m`` or ``P_rect_03``) or KITTI's
    ``calib_cam_to_cam.txt`` (``P_rect_02``, ``P_rect_03``), for images of ``size``."""
    text = path.read_text(encoding="utf-8")
    if text.lstrip().startswith("{"):
        try:
            data = json.loads(text)
            if "K" in data:
                K = np.asarray(data["K"], dtype=np.float64)
                projection = np.hstack((K, np.zeros((3, 1))))
            else:
                projection = np.asarray(data["P_rect_02"], dtype=np.float64)
            return _camera_from(projection, data.get("P_rect_03"), size, data.get("baseline_m"))
        except (KeyError, ValueError, TypeError) as exc:
            raise ValueError(f"{path}: not a calibration (K or P_rect_02): {exc}") from None
    values = read_key_values(path)
    if "P_rect_02" not in values or values["P_rect_02"].size != 12:
        raise ValueError(f"{path}: no P_rect_02 (3 × 4)")
    return _camera_from(values["P_rect_02"], values.get("P_rect_03"), size, None)


def inspect_calibration(path: Path, declared: str) -> Inspected:
    """The ``calibration`` kind's check (``contract.artifacts.Inspect``): read as a
    prediction job reads it; its focal length and stereo baseline kept."""
    limit_size(path, MAX_CALIBRATION_BYTES, "calibration files")
    try:
        camera = read_calibration_file(path, (KITTI_WIDTH, KITTI_HEIGHT))
    except ValueError as exc:  # UnicodeDecodeError too
        reason = text_of(exc).replace(f"{path}: ", "")
        raise ArtifactRefused(f"is not a camera calibration: {reason}") from exc
    is_json = path.read_bytes().lstrip().startswith(b"{")
    meta = {"focal_px": float(camera.K[0, 0]), "baseline_m": camera.baseline_m}
    return Inspected("application/json" if is_json else "text/plain", meta)


def image_files(folder: Path) -> list[Path]:
    """The PNG and JPEG images of ``folder`` (or of its ``data/``, KITTI raw's layout) by
    name, previews (``*.color.png``) left out; every reader of an image folder lists it so."""
    folder = Path(folder)
    if (folder / "data").is_dir():
        folder = folder / "data"
    return sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.endswith(".color.png")
    )


@dataclass(frozen=True)
class Drive:
    """A drive folder's frames, matched by name."""

    folder: Path
    camera: PinholeCamera
    names: tuple[str, ...]
    """Frame names (file stems), in order."""
    left: tuple[Path, ...]
    right: tuple[Path, ...] | None
    depth: tuple[Path | None, ...] | None
    """A depth PNG per frame (None where a frame has none), or None without depth."""
    poses: np.ndarray | None
    """(N, 4, 4) ``cam0_T_cami`` when the drive has poses.txt."""
    velodyne: tuple[Path | None, ...] | None = None
    """A LiDAR scan per frame (``velodyne/NAME.bin``; None where a frame has none), or None
    without ``velodyne/``."""


def read_drive(folder: Path) -> Drive:
    """A drive folder (see the module's docstring); ValueError naming what is missing or
    inconsistent."""
    folder = Path(folder)
    left_dir = folder / "image_02"
    if not left_dir.is_dir():
        raise ValueError(f"{folder}: no image_02/ folder (the left camera's images)")
    left = image_files(left_dir)
    if not left:
        raise ValueError(f"{left_dir}: no PNG or JPEG images")
    names = tuple(p.stem for p in left)
    first = read_image(left[0])
    camera = read_calibration(folder, (first.shape[1], first.shape[0]))
    right = None
    if (folder / "image_03").is_dir():
        by_name = {p.stem: p for p in image_files(folder / "image_03")}
        missing = [n for n in names if n not in by_name]
        if missing:
            raise ValueError(f"{folder / 'image_03'}: no right image for {missing[:3]}")
        right = tuple(by_name[n] for n in names)
    depth = None
    for candidate in (folder / "depth", folder / "proj_depth" / "groundtruth" / "image_02"):
        if candidate.is_dir():
            by_name = {p.stem: p for p in candidate.glob("*.png")}
            depth = tuple(by_name.get(n) for n in names)
            break
    poses = None
    if (folder / "poses.txt").is_file():
        poses = read_poses(folder / "poses.txt")
        if len(poses) != len(names):
            raise ValueError(f"{folder / 'poses.txt'}: {len(poses)} poses for {len(names)} frames")
    velodyne = None
    for candidate in (folder / "velodyne", folder / "velodyne_points" / "data"):
        if candidate.is_dir():
            by_name = {p.stem: p for p in candidate.glob("*.bin")}
            velodyne = tuple(by_name.get(n) for n in names)
            break
    return Drive(folder, camera, names, tuple(left), right, depth, poses, velodyne)
