"""Simulated drives in KITTI's layout, with dense depth and poses: a random street per drive
(``scene``), a camera at a random height, pitch and roll driving down a lane at a random
speed (stop-and-go included) with a little yaw, and a right camera one baseline to its right.

A drive folder gets ``image_02/`` (left), ``image_03/`` (right, when stereo), ``depth/``
(KITTI depth PNGs, dense except the sky), ``calib.json`` (``K`` at the image size,
``baseline_m``, ``width``, ``height``) and ``poses.txt`` (KITTI odometry format).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from contract.vocabulary import Say
from services.depth.camera import KITTI_HEIGHT_M, PinholeCamera, kitti_camera
from services.depth.render import render
from services.depth.scene import random_scene
from services.lib.images import write_image
from services.lib.kitti import write_depth_png, write_poses

FPS = 10.0
"""KITTI raw's frame rate."""


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Camera orientation in the street frame: yaw about y (down), pitch about x, roll about z."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    about_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    about_x = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    about_z = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return about_y @ about_x @ about_z


def drive_motion(seed: int, frames: int, ego_x_m: float, fps: float = FPS) -> np.ndarray:
    """(frames, 4, 4) left camera poses in the street frame along a seeded path: height
    1.5–1.8 m, pitch ±1.5°, roll ±0.7°, 0–14 m/s (a quarter of drives standing still), a slow
    yaw swing of ±2°."""
    rng = np.random.default_rng([seed, 77])
    height = KITTI_HEIGHT_M + rng.uniform(-0.15, 0.15)
    pitch, roll = np.radians(rng.uniform(-1.5, 1.5)), np.radians(rng.uniform(-0.7, 0.7))
    speed = 0.0 if rng.random() < 0.25 else rng.uniform(1, 14)
    yaw_amplitude, yaw_period = np.radians(rng.uniform(0, 2)), rng.uniform(3, 10)
    phase = rng.uniform(0, 2 * np.pi)
    t = np.arange(frames) / fps
    yaw = yaw_amplitude * np.sin(2 * np.pi * t / yaw_period + phase)
    z = speed * t
    x = ego_x_m + np.cumsum(np.sin(yaw) * speed / fps) - np.sin(yaw[0]) * speed / fps
    poses = np.tile(np.eye(4), (frames, 1, 1))
    for i in range(frames):  # a handful of frames, not pixels
        bounce = np.radians(rng.normal(0, 0.1))
        poses[i, :3, :3] = _rotation(yaw[i], pitch + bounce, roll)
        poses[i, :3, 3] = (x[i], -height + rng.normal(0, 0.005), z[i])
    return poses


def simulate_drive(
    out_dir: Path,
    *,
    frames: int = 5,
    stereo: bool = False,
    seed: int = 0,
    camera: PinholeCamera | None = None,
    progress: Say | None = None,
) -> Path:
    """Render one drive of ``frames`` frames at 10 Hz into ``out_dir`` (see the module's
    docstring); the camera is KITTI's at 1242 × 375 unless given."""
    if frames < 1:
        raise ValueError(f"--frames {frames}: a drive needs at least one frame")
    camera = camera or kitti_camera()
    scene = random_scene(seed, length_m=60.0 + frames * 14 / FPS + 100)
    poses = drive_motion(seed, frames, scene.ego_x_m)
    left_T_right = np.eye(4)
    left_T_right[0, 3] = camera.baseline_m
    for i, street_T_camera in enumerate(poses):
        name = f"{i:010d}"
        left = render(scene, camera, street_T_camera, time_s=i / FPS, noise_seed=2 * i)
        write_image(out_dir / "image_02" / f"{name}.png", left.image)
        write_depth_png(out_dir / "depth" / f"{name}.png", left.depth_m)
        if stereo:
            right = render(
                scene, camera, street_T_camera @ left_T_right, time_s=i / FPS, noise_seed=2 * i + 1
            )
            write_image(out_dir / "image_03" / f"{name}.png", right.image)
        if progress:
            progress(f"frame {i + 1}/{frames}")
    write_poses(out_dir / "poses.txt", np.linalg.inv(poses[0]) @ poses)
    calib = camera.to_json()
    (out_dir / "calib.json").write_text(json.dumps(calib, indent=1))
    return out_dir


def simulate_dataset(
    root: Path,
    *,
    drives: int,
    frames: int,
    stereo: bool,
    seed: int,
    camera: PinholeCamera,
    progress: Say | None = None,
) -> list[Path]:
    """``drives`` drives of ``frames`` frames in ``root/drive_NNNN`` (seeds ``seed`` + k);
    a drive already complete on disk is kept, so an interrupted run resumes."""
    folders = []
    for k in range(drives):
        folder = root / f"drive_{k:04d}"
        if not (folder / "poses.txt").is_file():
            simulate_drive(folder, frames=frames, stereo=stereo, seed=seed + k, camera=camera)
        folders.append(folder)
        if progress:
            progress(f"drive {k + 1}/{drives}")
    return folders
