"""``vista odometry run``: a folder of frames → relative motions → a trajectory with its
uncertainty.

Frame i (``NNNNNN.png``, in name order) is taken at i / fps seconds. Each consecutive pair
gives the camera's motion in the first frame's frame, a confidence (0–1) and, when the
pair cannot be trusted, a reason; the motions are chained in SE(2). A flagged pair's motion
is replaced by the one before it (a robot does not stop dead between two frames) and its
uncertainty is that of a guess.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from services.odometry import se2
from services.odometry.camera import Camera
from services.odometry.phase import pair_motion
from services.odometry.tum import Trajectory2D

METHODS = ("phase",)
Progress = Callable[[float, str], None]

MIN_RESPONSE = 0.08
"""Below this phase-correlation peak the frames did not match (textureless, blurred, too
far apart)."""
GUESS_SIGMA_MM = 5.0
GUESS_SIGMA_DEG = 1.0


@dataclass(frozen=True)
class Steps:
    motion: np.ndarray
    """(N−1, 3) mm, mm, rad: each pair's camera motion in the first frame's frame."""
    confidence: np.ndarray
    """(N−1,) 0–1."""
    reasons: list[str | None]
    """Why a pair is flagged (None: trusted)."""
    sigma: np.ndarray
    """(N−1, 3) the expected error of each motion: mm, mm, rad."""


@dataclass(frozen=True)
class OdometryRun:
    trajectory: Trajectory2D
    steps: Steps
    method: str
    seconds: float
    """Estimation time (not reading the frames)."""
    sigma_xy_mm: np.ndarray
    """(N,) the position's standard deviation, growing with the distance."""

    @property
    def pairs_per_s(self) -> float:
        return len(self.steps.motion) / self.seconds if self.seconds > 0 else float("inf")

    @property
    def flagged(self) -> int:
        return sum(r is not None for r in self.steps.reasons)


def frame_files(folder: Path) -> list[Path]:
    """The frames in name order; ValueError when there are fewer than two."""
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder of frames")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png")
    if len(files) < 2:
        raise ValueError(f"{folder}: needs at least 2 PNG frames, found {len(files)}")
    return files


def read_frames(files: list[Path], camera: Camera) -> Iterator[np.ndarray]:
    for path in files:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ValueError(f"{path}: not an image OpenCV can read")
        if image.shape != (camera.height, camera.width):
            raise ValueError(
                f"{path}: {image.shape[1]} × {image.shape[0]} pixels, but camera.json says "
                f"{camera.width} × {camera.height}"
            )
        yield image


def phase_steps(
    frames: Iterator[np.ndarray], camera: Camera, count: int, progress: Progress
) -> tuple[Steps, float]:
    """The peer: phase correlation with a Fourier–Mellin turn, pair by pair."""
    motion, confidence, reasons = [], [], []
    spent = 0.0
    previous = next(frames)
    for k, frame in enumerate(frames):
        started = time.perf_counter()
        pair = pair_motion(previous, frame)
        spent += time.perf_counter() - started
        motion.append(
            [pair.dx_px * camera.mm_per_px, pair.dy_px * camera.mm_per_px, pair.dtheta_rad]
        )
        confidence.append(min(1.0, pair.response / 0.5))
        reasons.append(None if pair.response >= MIN_RESPONSE else "the frames do not match")
        previous = frame
        if k % 100 == 0:
            progress((k + 1) / count, f"pair {k + 1} of {count}")
    sigma = np.tile([0.03, 0.03, np.radians(0.3)], (len(motion), 1))
    return Steps(np.array(motion), np.array(confidence), reasons, sigma), spent


def _bridged(steps: Steps) -> Steps:
    """Flagged pairs take the last trusted motion before them (none: standing still) and a
    guess's uncertainty."""
    trusted = np.array([reason is None for reason in steps.reasons])
    index = np.maximum.accumulate(np.where(trusted, np.arange(len(trusted)), -1))
    padded = np.vstack([np.zeros(3), steps.motion])
    motion = padded[index + 1]
    guess = np.array([GUESS_SIGMA_MM, GUESS_SIGMA_MM, np.radians(GUESS_SIGMA_DEG)])
    sigma = np.where(trusted[:, None], steps.sigma, guess)
    return Steps(motion, steps.confidence, steps.reasons, sigma)


def position_sigma(steps: Steps) -> np.ndarray:
    """(N,) position standard deviation: the steps' own errors add up, and the heading's
    error turns every later step."""
    heading_var = np.concatenate([[0.0], np.cumsum(steps.sigma[:, 2] ** 2)])
    length = np.hypot(steps.motion[:, 0], steps.motion[:, 1])
    step_var = steps.sigma[:, 0] ** 2 + steps.sigma[:, 1] ** 2 + heading_var[:-1] * length**2
    return np.sqrt(np.concatenate([[0.0], np.cumsum(step_var)]))


def run_odometry(
    folder: Path,
    camera: Camera,
    method: str = "phase",
    progress: Progress | None = None,
) -> OdometryRun:
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    report = progress or (lambda fraction, message: None)
    files = frame_files(folder)
    steps, seconds = phase_steps(read_frames(files, camera), camera, len(files) - 1, report)
    steps = _bridged(steps)
    times = np.arange(len(files)) / camera.fps
    trajectory = Trajectory2D(times, se2.integrate(steps.motion))
    return OdometryRun(trajectory, steps, method, seconds, position_sigma(steps))
