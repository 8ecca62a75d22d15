"""Training data for the depth networks: drive folders or plain image folders, loaded at one
size into arrays (8-bit images, float depth), with what each loss needs — the right image,
the neighbouring frames, the intrinsics at that size and the relative poses.

A folder is a drive (``kitti.read_drive``) when it has ``image_02/``; otherwise its images
(PNG, JPEG) are frames with nothing else known (enough for distillation).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.vocabulary import Progress
from services.depth.drive import image_files, read_drive
from services.lib.images import read_image
from services.lib.kitti import read_depth_png


@dataclass(frozen=True)
class FrameSet:
    """N frames at (height, width)."""

    images: np.ndarray
    """(N, 3, H, W) uint8 RGB (left camera)."""
    right: np.ndarray | None
    """(N, 3, H, W) uint8 right camera, when every frame has one."""
    depth_m: np.ndarray | None
    """(N, 1, H, W) float32 depth at this size (0 = none), when every frame has some."""
    K: np.ndarray
    """(N, 3, 3) float32 intrinsics at this size (a frame without calibration gets a
    nominal KITTI-like one: only photometric losses use K)."""
    baseline_m: np.ndarray
    """(N,) float32."""
    previous: np.ndarray
    """(N,) index of the frame before in the same drive, −1 if none."""
    following: np.ndarray
    """(N,) index of the frame after in the same drive, −1 if none."""
    previous_T_cam: np.ndarray
    """(N, 4, 4) this frame's points in the previous frame's camera (identity if unknown)."""
    following_T_cam: np.ndarray
    has_poses: np.ndarray
    """(N,) bool: the drive gave poses."""
    group: np.ndarray
    """(N,) which folder a frame came from (splits keep a drive together)."""

    def __len__(self) -> int:
        return len(self.images)


def _resize_depth(depth_m: np.ndarray, width: int, height: int) -> np.ndarray:
    """Nearest valid depth when shrinking a (possibly sparse) depth map: the minimum over each
    target cell would bias, so each cell keeps its centre-most sample (cv2's nearest)."""
    import cv2

    if depth_m.shape == (height, width):
        return depth_m
    return cv2.resize(depth_m, (width, height), interpolation=cv2.INTER_NEAREST)


def _resize_image(image: np.ndarray, width: int, height: int) -> np.ndarray:
    import cv2

    if image.shape[:2] == (height, width):
        return image
    shrink = image.shape[1] > width
    return cv2.resize(
        image, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    )


def nominal_K(width: int, height: int) -> np.ndarray:
    """KITTI's intrinsics scaled to (width, height): for images whose camera is unknown."""
    from services.depth.camera import kitti_camera

    return kitti_camera().resized(width, height).K


def _scan_depths(drive, width: int, height: int) -> list[np.ndarray] | None:  # noqa: ANN001 - a kitti.Drive
    """Each frame's LiDAR scan projected at (width, height), when every frame has one."""
    from services.depth.lidar import lidar_depth, read_lidar_calibration
    from services.lib.kitti import read_velodyne

    if drive.velodyne is None or any(p is None for p in drive.velodyne):
        return None
    calibration = read_lidar_calibration(drive.folder)
    size = (drive.camera.width, drive.camera.height)
    return [
        lidar_depth(read_velodyne(path), calibration, size, (width, height))
        for path in drive.velodyne
    ]


def load_frames(
    folders: list[Path],
    width: int,
    height: int,
    *,
    lidar: bool = False,
    progress: Progress | None = None,
) -> FrameSet:
    """Every frame of ``folders`` at (width, height); ValueError naming a bad folder or file.
    With ``lidar``, a drive's depth comes from its scans (``velodyne/`` projected at this
    size through its calibration, the nearest return per pixel) where it has them."""
    say = progress or (lambda fraction, message: None)
    if width % 32 or height % 32 or min(width, height) < 64:
        raise ValueError(
            f"{width} × {height}: network input sizes are multiples of 32, at least 64"
        )
    images, rights, depths, Ks, baselines = [], [], [], [], []
    previous, following, before, after, posed, group = [], [], [], [], [], []
    for g, folder in enumerate(folders):
        folder = Path(folder)
        if not folder.is_dir():
            raise ValueError(f"{folder}: no such folder")
        start = len(images)
        if (folder / "image_02").is_dir():
            drive = read_drive(folder)
            camera = drive.camera
            paths = drive.left
            K = camera.resized(width, height).K
            baseline = camera.baseline_m
            right_paths = drive.right
            depth_paths = (
                drive.depth
                if drive.depth is not None and all(p is not None for p in drive.depth)
                else None
            )
            scans = _scan_depths(drive, width, height) if lidar else None
            poses = drive.poses
        else:
            paths = image_files(folder)
            if not paths:
                raise ValueError(f"{folder}: no image_02/ and no PNG or JPEG images")
            K, baseline = nominal_K(width, height), 0.0
            right_paths, depth_paths, poses, scans = None, None, None, None
        for k, path in enumerate(paths):
            images.append(_resize_image(read_image(path), width, height).transpose(2, 0, 1))
            rights.append(
                _resize_image(read_image(right_paths[k]), width, height).transpose(2, 0, 1)
                if right_paths
                else None
            )
            if scans is not None:
                depths.append(scans[k][None])
            else:
                depths.append(
                    _resize_depth(read_depth_png(depth_paths[k]), width, height)[None]
                    if depth_paths
                    else None
                )
            Ks.append(K)
            baselines.append(baseline)
            index = start + k
            previous.append(index - 1 if k > 0 else -1)
            following.append(index + 1 if k + 1 < len(paths) else -1)
            if poses is not None:
                before.append(np.linalg.inv(poses[k - 1]) @ poses[k] if k > 0 else np.eye(4))
                after.append(
                    np.linalg.inv(poses[k + 1]) @ poses[k] if k + 1 < len(paths) else np.eye(4)
                )
            else:
                before.append(np.eye(4))
                after.append(np.eye(4))
            posed.append(poses is not None)
            group.append(g)
        say((g + 1) / len(folders), f"loaded {folder} ({len(paths)} frames)")
    if not images:
        raise ValueError("no frames to load")
    every_right = all(r is not None for r in rights)
    every_depth = all(d is not None for d in depths)
    return FrameSet(
        images=np.stack(images),
        right=np.stack(rights) if every_right else None,
        depth_m=np.stack(depths).astype(np.float32) if every_depth else None,
        K=np.stack(Ks).astype(np.float32),
        baseline_m=np.array(baselines, np.float32),
        previous=np.array(previous),
        following=np.array(following),
        previous_T_cam=np.stack(before).astype(np.float32),
        following_T_cam=np.stack(after).astype(np.float32),
        has_poses=np.array(posed),
        group=np.array(group),
    )


def split_by_group(
    frames: FrameSet, val_fraction: float, seed: int, val_groups: tuple[int, ...] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation frame indices, whole folders to one side (frames of a drive
    are alike): the folders ``val_groups`` validate, else a random ``val_fraction`` of them;
    with a single folder, its last ``val_fraction`` of frames validate."""
    if val_groups is not None:
        is_val = np.isin(frames.group, val_groups)
        return np.flatnonzero(~is_val), np.flatnonzero(is_val)
    groups = np.unique(frames.group)
    if len(groups) == 1:
        count = len(frames)
        val = max(1, int(round(count * val_fraction))) if count > 1 else 0
        order = np.arange(count)
        return order[: count - val], order[count - val :]
    rng = np.random.default_rng([seed, 5])
    chosen = rng.permutation(groups)[: max(1, int(round(len(groups) * val_fraction)))]
    is_val = np.isin(frames.group, chosen)
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)
