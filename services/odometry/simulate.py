"""``vista odometry simulate``: a floor-camera sequence with its ground truth.

``OUT/frames/NNNNNN.png`` (8-bit grey, the camera's full resolution), ``OUT/camera.json``
and ``OUT/truth.tum`` (frame i's camera pose in the frame of camera 0).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from contract.vocabulary import Count, Say
from services.odometry.camera import FloorCamera
from services.odometry.drive import Command, Robot, drive, path_commands
from services.odometry.floors import IMAGE_MM_PER_PX, make_floor
from services.odometry.render import Effects, exposures, render
from services.odometry.tum import Trajectory2D, write_tum


@dataclass(frozen=True)
class Simulated:
    folder: Path
    camera: FloorCamera
    truth: Trajectory2D
    distance_mm: float


def frame_name(index: int) -> str:
    return f"{index:06d}.png"


def simulate_sequence(
    out_dir: Path,
    *,
    floor: str = "concrete",
    floor_mm_per_px: float = IMAGE_MM_PER_PX,
    path: str = "loop",
    seconds: float | None = None,
    fps: float = 60.0,
    seed: int = 0,
    camera: FloorCamera | None = None,
    effects: Effects = Effects(),
    robot: Robot = Robot(),
    commands: list[Command] | None = None,
    progress: Say | None = None,
    frame_progress: Count | None = None,
) -> Simulated:
    """Drive ``path`` (or the given ``commands``) over ``floor`` (an image floor's pixel
    covering ``floor_mm_per_px``) and write what the camera saw and where it was;
    ``frame_progress(done, total)`` hears of every frame written."""
    say = progress or (lambda message: None)
    camera = camera or FloorCamera.thesis(fps=fps)
    rng = np.random.default_rng(seed)
    say(f"floor {floor}")
    ground = make_floor(floor, seed, floor_mm_per_px)
    motion = drive(commands or path_commands(path, seconds=seconds, seed=seed), robot)
    times = np.arange(0.0, motion.seconds + 1e-9, 1.0 / camera.fps)
    exposure = exposures(camera, times, effects, rng)
    truth = Trajectory2D(times, motion.at(times), camera.height_mm - exposure.height_mm)
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    say(
        f"rendering {len(times)} frames ({motion.distance_mm / 1000:.2f} m, {motion.seconds:.1f} s)"
    )
    for index, image in enumerate(render(ground, camera, motion, times, effects, rng, exposure)):
        cv2.imwrite(str(frames_dir / frame_name(index)), image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if progress and index and index % 500 == 0:
            say(f"  {index} of {len(times)} frames")
        if frame_progress:
            frame_progress(index + 1, len(times))
    (out_dir / "camera.json").write_text(json.dumps(camera.document(), indent=1) + "\n")
    write_tum(out_dir / "truth.tum", truth)
    return Simulated(out_dir, camera, truth, motion.distance_mm)
