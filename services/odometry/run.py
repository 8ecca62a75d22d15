"""``vista odometry run``: a folder of frames → relative motions → a trajectory with its
uncertainty.

Frame i (``NNNNNN.png``, in name order) is taken at i / fps seconds. Each consecutive pair
gives the camera's motion in the first frame's frame, a confidence (0–1), when its
alignment failed a reason (a flag), and when it is less sure than usual a warning; the
motions are chained in SE(2). A flagged pair's motion is replaced by the one before it (a
robot does not stop dead between two frames) and its uncertainty is that of a guess; a
warned pair keeps its motion with a larger uncertainty.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.vocabulary import Progress
from services.odometry import se2
from services.odometry.camera import FloorCamera
from services.odometry.direct import LEVELS, align, flat_field, prepare, seed_px, warm_up
from services.odometry.frames import frame_files, read_frame, read_frames, read_frames_at_once
from services.odometry.kinds import OdometryParams
from services.odometry.oenet import oenet_motions, oenet_sigma
from services.odometry.phase import pair_motion
from services.odometry.tum import Trajectory2D

MIN_RESPONSE = 0.08
"""Below this phase-correlation peak the frames did not match (textureless, blurred, too
far apart)."""
FLAT_FIELD_FRAMES = 200
"""Frames (spread over the sequence) whose mean gives the light's fixed pattern."""
DIRECT_SIGMA_FLOOR = np.array([0.01, 0.01, np.radians(0.004)])
"""Per-pair errors the alignment's covariance does not see (interpolation, blur, the
sensor's bias): the per-step RMSE of vista's method on the simulated floors."""
SCALE_SIGMA = 5e-4
"""Relative error of the steps' lengths that they share, so it does not average out: at a
steady speed interpolation pulls every step's sub-pixel part the same way (0.03 % on the
simulated loop), and a real camera's height known to 0.05 mm adds as much."""
LOW_TEXTURE_SIGMA = np.array([0.04, 0.04, np.radians(0.02)])
"""A warned pair's least error: the median per-step error of the faintest floor, blur and
noise of the bench's sweep."""
MAX_JUMP_MM = 2.8
MAX_JUMP_RAD = np.radians(2.0)
"""What a step may differ from the one before: 1 g for 1/60 s moves 2.8 mm."""
JUMP = "a change of motion no robot makes between two frames"
GUESS_SIGMA_MM = 5.0
GUESS_SIGMA_DEG = 1.0


@dataclass(frozen=True)
class Steps:
    motion: np.ndarray
    """(N−1, 3) mm, mm, rad: each pair's camera motion in the first frame's frame."""
    confidence: np.ndarray
    """(N−1,) 0–1."""
    reasons: list[str | None]
    """Why a pair is flagged: its alignment failed (None: it did not)."""
    sigma: np.ndarray
    """(N−1, 3) the expected error of each motion: mm, mm, rad."""
    warnings: list[str | None]
    """Why a measured pair is less sure than usual (None: as usual)."""


@dataclass(frozen=True)
class OdometryRun:
    trajectory: Trajectory2D
    steps: Steps
    method: str
    seconds: float
    """Time to read the frames and estimate the motions."""
    covariance: np.ndarray
    """(N, 3, 3) each pose's covariance (mm², mm·rad, rad²), growing along the way."""

    @property
    def sigma_xy_mm(self) -> np.ndarray:
        """(N,) the position's standard deviation (the root of the covariance's x–y trace:
        the expected size of the position error)."""
        return np.sqrt(self.covariance[:, 0, 0] + self.covariance[:, 1, 1])

    @property
    def pairs_per_s(self) -> float:
        return len(self.steps.motion) / self.seconds if self.seconds > 0 else float("inf")

    @property
    def flagged(self) -> int:
        return sum(r is not None for r in self.steps.reasons)

    @property
    def warned(self) -> int:
        return sum(w is not None for w in self.steps.warnings)


def _phase_run(
    files: list[Path], camera: FloorCamera, tick: Callable[[], None], ahead: bool
) -> Steps:
    """The peer on consecutive frames: phase correlation with a Fourier–Mellin turn
    (``ahead``: as ``read_frames``)."""
    motion, confidence, reasons = [], [], []
    frames = read_frames(files, camera, ahead=ahead)
    previous = next(frames)
    for frame in frames:
        tick()
        pair = pair_motion(previous, frame)
        motion.append(
            [pair.dx_px * camera.mm_per_px, pair.dy_px * camera.mm_per_px, pair.dtheta_rad]
        )
        confidence.append(min(1.0, pair.response / 0.5))
        reasons.append(None if pair.response >= MIN_RESPONSE else "the frames do not match")
        previous = frame
    sigma = np.tile([0.03, 0.03, np.radians(0.3)], (len(motion), 1))
    return Steps(np.array(motion), np.array(confidence), reasons, sigma, [None] * len(motion))


def _implausible(motion_mm: np.ndarray, expected_mm: np.ndarray) -> bool:
    """A change of motion between two frames that no robot makes (about 1 g)."""
    jump = motion_mm - expected_mm
    return bool(np.hypot(jump[0], jump[1]) > MAX_JUMP_MM or abs(jump[2]) > MAX_JUMP_RAD)


def _direct_run(
    files: list[Path],
    camera: FloorCamera,
    flat: np.ndarray,
    tick: Callable[[], None],
    ahead: bool,
) -> Steps:
    """vista's method on consecutive frames: each pair aligned from the previous pair's
    motion, or from phase correlation when that failed or jumped implausibly (``ahead``:
    as ``read_frames``)."""
    frames = read_frames(files, camera, ahead=ahead)
    motion, confidence, reasons, warnings, sigma = [], [], [], [], []
    previous = prepare(next(frames), flat)
    guess, trusted, sure = None, False, False
    px = np.array([camera.mm_per_px, camera.mm_per_px, 1.0])
    for frame in frames:
        tick()
        current = prepare(frame, flat)
        if guess is None:
            guess = seed_px(previous, current)
        # a sure previous motion starts at half size; else (a start, a failure, a faint
        # floor whose full-size gradients are mostly noise) the quarter size's averaged
        # pixels lead
        found = align(previous, current, guess, coarsest=1 if sure else LEVELS - 1)
        reason = found.reason
        if trusted and reason is None and _implausible(found.motion_px * px, guess * px):
            reason = JUMP
        if reason is not None:
            retry = align(previous, current, seed_px(previous, current))
            jumped = trusted and _implausible(retry.motion_px * px, guess * px)
            if retry.reason is None and not jumped:
                found, reason = retry, None
        motion.append(found.motion_px * px)
        deviation = np.sqrt(np.maximum(np.diag(found.covariance), 0.0)) * px
        floor = LOW_TEXTURE_SIGMA if found.warning else DIRECT_SIGMA_FLOOR
        sigma.append(np.maximum(deviation, floor))
        confidence.append(
            float(min(1.0, max(found.sharpness, 0.0)) * min(1.0, found.overlap / 0.8))
            * float(np.exp(-found.residual / 16.0))
        )
        reasons.append(reason)
        warnings.append(found.warning)
        trusted = reason is None
        sure = trusted and found.warning is None
        if trusted:
            guess = found.motion_px
        previous = current
    return Steps(np.array(motion), np.array(confidence), reasons, np.array(sigma), warnings)


def in_parts(
    files: list[Path],
    threads: int,
    run_part: Callable[[list[Path], Callable[[], None], bool], Steps],
    progress: Progress,
) -> Steps:
    """``run_part`` on ``threads`` runs of consecutive frames at once (each reads its own
    frames; OpenCV and NumPy let go of the interpreter while they work), joined; each
    calls its ``tick`` once per pair, and ``progress`` hears of every 1 %. A part decodes
    its frames ahead on a thread of their own only while the parts leave a core free
    (its third argument)."""
    count = len(files) - 1
    parts = max(1, min(threads, count // 100))
    bounds = np.linspace(0, count, parts + 1).round().astype(int)
    runs = [files[bounds[k] : bounds[k + 1] + 1] for k in range(parts)]
    done = itertools.count(1)
    every = max(1, count // 100)

    def tick() -> None:
        pairs = next(done)  # atomic under the interpreter's lock
        if pairs % every == 0:
            progress(pairs / count, f"pair {pairs} of {count}")

    ahead = parts < threads
    if parts == 1:
        results = [run_part(runs[0], tick, ahead)]
    else:
        with ThreadPoolExecutor(parts) as pool:
            results = list(pool.map(lambda run: run_part(run, tick, ahead), runs))
    return Steps(
        np.concatenate([r.motion for r in results]),
        np.concatenate([r.confidence for r in results]),
        [reason for r in results for reason in r.reasons],
        np.concatenate([r.sigma for r in results]),
        [warning for r in results for warning in r.warnings],
    )


def direct_steps(files: list[Path], camera: FloorCamera, threads: int, progress: Progress) -> Steps:
    """vista's method on ``threads`` threads, all with the light's fixed pattern taken out
    (``flat_field`` of frames spread over the run)."""
    sample = files[:: max(1, len(files) // FLAT_FIELD_FRAMES)][:FLAT_FIELD_FRAMES]
    flat = flat_field(read_frames_at_once(sample, camera, threads))
    return in_parts(
        files,
        threads,
        lambda run, tick, ahead: _direct_run(run, camera, flat, tick, ahead),
        progress,
    )


def _bridged(steps: Steps) -> Steps:
    """Flagged pairs take the last trusted motion before them (none: standing still) and a
    guess's uncertainty."""
    trusted = np.array([reason is None for reason in steps.reasons])
    index = np.maximum.accumulate(np.where(trusted, np.arange(len(trusted)), -1))
    padded = np.vstack([np.zeros(3), steps.motion])
    guess = np.array([GUESS_SIGMA_MM, GUESS_SIGMA_MM, np.radians(GUESS_SIGMA_DEG)])
    sigma = np.where(trusted[:, None], steps.sigma, guess)
    return Steps(padded[index + 1], steps.confidence, steps.reasons, sigma, steps.warnings)


def pose_covariance(steps: Steps) -> np.ndarray:
    """(N, 3, 3) each pose's covariance (mm², mm·rad, rad²): the steps' own errors carried
    through the composition (a heading error turns every later position), and an error of
    scale the steps share growing with the way travelled (``se2.pose_covariances``)."""
    return se2.pose_covariances(steps.motion, steps.sigma, SCALE_SIGMA)


def oenet_steps(files: list[Path], camera: FloorCamera, model: Path, threads: int) -> Steps:
    """OE-Net's motions; its σ is the test RMSE it was exported with (it gives no
    confidence of its own, so nothing is flagged)."""

    motion = oenet_motions(model, read_frames(files, camera), camera, threads)
    sigma = np.tile(oenet_sigma(model, camera), (len(motion), 1))
    nothing = [None] * len(motion)
    return Steps(motion, np.ones(len(motion)), nothing, sigma, nothing)


def run_odometry(
    folder: Path,
    camera: FloorCamera,
    params: OdometryParams | None = None,
    *,
    model: Path | None = None,
    threads: int = 1,
    progress: Progress | None = None,
) -> OdometryRun:
    """The trajectory of the frames in ``folder`` by ``params.method`` (default vista's;
    ``oenet`` needs the ``model`` file that ``vista odometry train`` builds): what
    ``vista odometry run`` and the ``odometry.run`` job do."""
    method = (params or OdometryParams()).method
    if method == "oenet" and (model is None or not model.is_file()):
        raise ValueError(
            "OE-Net needs its model file (--model): build one with `vista odometry train "
            "DATA_DIR… -o MODEL.onnx` (simulate the training sequences with `vista odometry "
            "simulate`); `--method vista` needs no model"
        )
    report = progress or (lambda fraction, message: None)
    files = frame_files(folder)
    # The first frame read before the clock starts: it loads the PNG decoder's compiled
    # passes (0.3 s, once per process, which the method that ran first paid alone) and
    # names a frame that cannot be read before any work.
    read_frame(files[0], camera)
    if method == "vista":
        warm_up()
    started = time.perf_counter()
    if method == "phase":
        steps = in_parts(
            files,
            threads,
            lambda run, tick, ahead: _phase_run(run, camera, tick, ahead),
            report,
        )
    elif method == "oenet":
        steps = oenet_steps(files, camera, model, threads)
    else:
        steps = direct_steps(files, camera, threads, report)
    seconds = time.perf_counter() - started
    steps = _bridged(steps)
    times = np.arange(len(files)) / camera.fps
    trajectory = Trajectory2D(times, se2.integrate(steps.motion))
    return OdometryRun(trajectory, steps, method, seconds, pose_covariance(steps))
