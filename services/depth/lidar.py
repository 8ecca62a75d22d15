"""Sparse depth from the LiDAR a vehicle already carries: a Velodyne scan projected into
the left colour camera through the drive's calibration, as KITTI's depth benchmark does
(the nearest return per pixel, depth along the optical axis).

Calibration, in the drive folder or its parent (raw drives share their date folder's):

- ``calib.json``: ``P_rect_02`` (3 × 4), ``R_rect_00`` (3 × 3), ``cam0_T_velo`` (4 × 4);
- KITTI raw's ``calib_velo_to_cam.txt`` (``R``, ``T``) and ``calib_cam_to_cam.txt``
  (``R_rect_00``, ``P_rect_02``);
- the object benchmark's ``calib.txt`` (``P2``, ``R0_rect``, ``Tr_velo_to_cam``).

A velodyne point ``X`` (metres, x forward, y left, z up) maps to the pixel
``P_rect_02 · [R_rect_00 · cam0_T_velo · X]``; the projection is computed at the
calibration's image size and scaled to the size asked for.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.lib.kitti import read_key_values

MIN_DEPTH_M = 1e-3


@dataclass(frozen=True)
class LidarCalibration:
    P: np.ndarray
    """(3, 4) the left colour camera's rectified projection at the calibration's size."""
    rect_T_velo: np.ndarray
    """(4, 4) velodyne points into the rectified camera frame (R_rect_00 · cam0_T_velo)."""


def _homogeneous(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
    out[:3, 3] = np.asarray(translation, dtype=np.float64).reshape(3)
    return out


def _rect(rotation: np.ndarray) -> np.ndarray:
    return _homogeneous(rotation, np.zeros(3))


def read_lidar_calibration(folder: Path) -> LidarCalibration:
    """The velodyne-to-camera calibration of a drive (module docstring); ValueError naming
    what is missing."""
    folder = Path(folder)
    for place in (folder, folder.parent):
        json_path = place / "calib.json"
        if json_path.is_file():
            try:
                data = json.loads(json_path.read_text())
                return LidarCalibration(
                    np.asarray(data["P_rect_02"], dtype=np.float64).reshape(3, 4),
                    _rect(data["R_rect_00"]) @ np.asarray(data["cam0_T_velo"]).reshape(4, 4),
                )
            except (KeyError, ValueError, TypeError) as exc:
                raise ValueError(
                    f"{json_path}: no LiDAR calibration (P_rect_02, R_rect_00, cam0_T_velo): {exc}"
                ) from None
        velo_txt, cam_txt = place / "calib_velo_to_cam.txt", place / "calib_cam_to_cam.txt"
        if velo_txt.is_file() and cam_txt.is_file():
            velo, cam = read_key_values(velo_txt), read_key_values(cam_txt)
            try:
                return LidarCalibration(
                    cam["P_rect_02"].reshape(3, 4),
                    _rect(cam["R_rect_00"]) @ _homogeneous(velo["R"], velo["T"]),
                )
            except (KeyError, ValueError) as exc:
                raise ValueError(
                    f"{place}: calib_velo_to_cam.txt needs R and T, calib_cam_to_cam.txt "
                    f"R_rect_00 and P_rect_02 ({exc})"
                ) from None
        object_txt = place / "calib.txt"
        if object_txt.is_file():
            values = read_key_values(object_txt)
            try:
                velo_to_cam = np.vstack((values["Tr_velo_to_cam"].reshape(3, 4), [0, 0, 0, 1]))
                return LidarCalibration(
                    values["P2"].reshape(3, 4), _rect(values["R0_rect"]) @ velo_to_cam
                )
            except (KeyError, ValueError) as exc:
                raise ValueError(
                    f"{object_txt}: needs P2, R0_rect and Tr_velo_to_cam ({exc})"
                ) from None
    raise ValueError(
        f"{folder}: no LiDAR calibration here or in its parent (calib.json with P_rect_02, "
        "R_rect_00 and cam0_T_velo; calib_velo_to_cam.txt + calib_cam_to_cam.txt; or calib.txt)"
    )


def lidar_depth(
    points_velo: np.ndarray,
    calibration: LidarCalibration,
    calibration_size: tuple[int, int],
    size: tuple[int, int],
) -> np.ndarray:
    """(H, W) float32 sparse depth (metres along the optical axis, 0 = no return) at
    ``size`` (width, height) of images whose calibration is for ``calibration_size``: each
    pixel keeps its nearest return."""
    width, height = size
    sx, sy = width / calibration_size[0], height / calibration_size[1]
    # pixel centres at integers at both sizes (cv2.resize's convention)
    scale = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1.0]])
    P = scale @ calibration.P
    xyz1 = np.hstack((points_velo[:, :3].astype(np.float64), np.ones((len(points_velo), 1))))
    camera = xyz1 @ calibration.rect_T_velo.T
    ahead = camera[:, 2] > MIN_DEPTH_M
    pixels = camera[ahead] @ P.T
    depth = pixels[:, 2]
    u = np.rint(pixels[:, 0] / depth).astype(np.int64)
    v = np.rint(pixels[:, 1] / depth).astype(np.int64)
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    u, v, depth = u[inside], v[inside], depth[inside]
    out = np.full(height * width, np.inf)
    np.minimum.at(out, v * width + u, depth)
    out[~np.isfinite(out)] = 0
    return out.reshape(height, width).astype(np.float32)
