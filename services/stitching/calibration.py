"""Robot–sensor (hand–eye) calibration: find ``flange_T_sensor`` from pose pairs.

Every pair i holds the robot's reported ``base_T_flange_i`` (F_i) and the plate pose the
sensor measured, ``sensor_T_target_i`` (S_i). With X = flange_T_sensor and Z = base_T_target
(the plate, fixed in the base frame): ``F_i @ X @ S_i = Z`` for every i.

Three ways to solve it:

- ``thesis`` (thesis 6.1.1): a grid of points in the target frame mapped into the base
  frame through every pair; minimise the Frobenius norm of their per-point standard
  deviation over X with scipy's basin hopping (from the identity).
- OpenCV's closed forms (``tsai``, ``park``, ``horaud``, ``andreff``, ``daniilidis``), Z then
  averaged over the pairs.
- ``vista``: a closed-form start (Park–Martin on all pairs of motions), then a nonlinear
  least-squares fit of X and Z where each pair's residual is weighed by its own noise
  (robot repeatability carried into the plate's frame, plus the sensor's noise). A pair whose residual is far beyond its noise is dropped and the fit redone;
  the covariance of the fit gives X's uncertainty.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import get_args

import numpy as np
from scipy import optimize
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from services.lib.pointcloud.transforms import (
    adjoint,
    from_rotvec,
    invert,
    make_transform,
    to_rotvec,
)
from services.stitching.kinds import CalibrationMethod, NoiseModel, OpenCvMethod

METHODS: tuple[str, ...] = get_args(CalibrationMethod)
OPENCV_METHODS: tuple[str, ...] = get_args(OpenCvMethod)
MIN_PAIRS = 3

_axis = np.linspace(-50.0, 50.0, 5)
PLATE_POINTS_MM = np.stack(np.meshgrid(_axis, _axis, [0.0], indexing="ij"), -1).reshape(-1, 3)
"""Where the residual is measured: a 100 × 100 mm grid on the plate (target frame)."""
THESIS_GRID_MM = np.stack(np.meshgrid(_axis, _axis, [0.0, 25.0, 50.0], indexing="ij"), -1).reshape(
    -1, 3
)
"""The thesis's grid of N 3D points in the target frame (here 5 × 5 × 3 over 100 × 100 × 50 mm)."""
THESIS_TRANSLATION_SCALE_MM = 100.0
"""Basin hopping steps in rotation (rad) and translation / 100 mm, so one step size fits both."""


class CalibrationError(ValueError):
    """The pairs cannot give a calibration; the message says why."""


@dataclass(frozen=True)
class DroppedPair:
    index: int
    chi2: float
    """Its weighted squared residual when dropped (≈ 6 for a pair that fits its noise)."""
    residual_mm: float


@dataclass(frozen=True)
class HandEye:
    flange_T_sensor: np.ndarray
    base_T_target: np.ndarray
    method: str
    residual_mm: float
    """RMS distance, over the used pairs and the plate grid, between the plate points seen
    through each pair (F_i X S_i p) and through the fit (Z p)."""
    pair_residuals_mm: tuple[float, ...]
    """The same RMS per pair, for every pair given (dropped ones included)."""
    used_pairs: tuple[int, ...]
    dropped: tuple[DroppedPair, ...] = ()
    sigma_translation_mm: float | None = None
    """1σ of X's translation (root of the covariance's trace), from the fit."""
    sigma_rotation_deg: float | None = None
    seconds: float = 0.0
    details: dict = field(default_factory=dict)
    noise: NoiseModel | None = None
    """The noise the calibration was given (the vista method weighs the pairs by it; a
    bounded ICP stitch with this calibration bounds each scan by the robot's)."""


def check_pairs(base_T_flange: np.ndarray, sensor_T_target: np.ndarray) -> None:
    if base_T_flange.shape != sensor_T_target.shape or base_T_flange.shape[1:] != (4, 4):
        raise CalibrationError(
            f"need (k, 4, 4) pose arrays of equal length, got {base_T_flange.shape} "
            f"and {sensor_T_target.shape}"
        )
    if len(base_T_flange) < MIN_PAIRS:
        raise CalibrationError(
            f"a calibration needs at least {MIN_PAIRS} pairs, got {len(base_T_flange)}"
        )
    rotations = Rotation.from_matrix(base_T_flange[:, :3, :3])
    spread_deg = np.degrees((rotations[0].inv() * rotations).magnitude().max())
    if spread_deg < 1.0:
        raise CalibrationError(
            f"the robot orientations differ by at most {spread_deg:.2f}°: tilt and turn the "
            "sensor between poses (hand–eye calibration needs rotation about two axes)"
        )


def plate_residuals_mm(
    base_T_flange: np.ndarray,
    sensor_T_target: np.ndarray,
    flange_T_sensor: np.ndarray,
    base_T_target: np.ndarray,
) -> np.ndarray:
    """(k,) RMS distance per pair between plate points seen through the pair and the fit."""
    through_pair = base_T_flange @ flange_T_sensor @ sensor_T_target
    seen = np.einsum("kij,nj->kni", through_pair[:, :3, :3], PLATE_POINTS_MM)
    seen += through_pair[:, None, :3, 3]
    fit = PLATE_POINTS_MM @ base_T_target[:3, :3].T + base_T_target[:3, 3]
    return np.sqrt(np.mean(np.sum((seen - fit) ** 2, axis=-1), axis=-1))


def mean_transform(transforms: np.ndarray) -> np.ndarray:
    """Chordal mean of (k, 4, 4) rigid transforms."""
    rotation = Rotation.from_matrix(transforms[:, :3, :3]).mean().as_matrix()
    return make_transform(rotation, transforms[:, :3, 3].mean(axis=0))


def _finish(
    method: str,
    base_T_flange: np.ndarray,
    sensor_T_target: np.ndarray,
    flange_T_sensor: np.ndarray,
    base_T_target: np.ndarray | None,
    used: np.ndarray,
    started: float,
    **extra,
) -> HandEye:
    if base_T_target is None:
        base_T_target = mean_transform(
            base_T_flange[used] @ flange_T_sensor @ sensor_T_target[used]
        )
    per_pair = plate_residuals_mm(base_T_flange, sensor_T_target, flange_T_sensor, base_T_target)
    return HandEye(
        flange_T_sensor=flange_T_sensor,
        base_T_target=base_T_target,
        method=method,
        residual_mm=float(np.sqrt(np.mean(per_pair[used] ** 2))),
        pair_residuals_mm=tuple(float(r) for r in per_pair),
        used_pairs=tuple(int(i) for i in used),
        seconds=time.perf_counter() - started,
        **extra,
    )


# --------------------------------------------------------------------------- OpenCV


def calibrate_opencv(
    base_T_flange: np.ndarray, sensor_T_target: np.ndarray, method: str
) -> HandEye:
    """OpenCV's ``calibrateHandEye`` (eye-in-hand: gripper = flange, camera = sensor)."""
    import cv2

    if method not in OPENCV_METHODS:
        raise CalibrationError(
            f"unknown OpenCV method {method!r}; one of {', '.join(OPENCV_METHODS)}"
        )
    check_pairs(base_T_flange, sensor_T_target)
    started = time.perf_counter()
    rotation, translation = cv2.calibrateHandEye(
        list(base_T_flange[:, :3, :3]),
        list(base_T_flange[:, :3, 3:]),
        list(sensor_T_target[:, :3, :3]),
        list(sensor_T_target[:, :3, 3:]),
        method=getattr(cv2, f"CALIB_HAND_EYE_{method.upper()}"),
    )
    flange_T_sensor = make_transform(rotation, translation.ravel())
    used = np.arange(len(base_T_flange))
    return _finish(method, base_T_flange, sensor_T_target, flange_T_sensor, None, used, started)


# --------------------------------------------------------------------------- thesis


def _thesis_transform(x: np.ndarray) -> np.ndarray:
    return from_rotvec(x[:3], x[3:] * THESIS_TRANSLATION_SCALE_MM)


def thesis_objective(
    x: np.ndarray, base_T_flange: np.ndarray, sensor_T_target: np.ndarray
) -> float:
    """‖σ(Y)‖_F: the grid mapped into the base frame through every pair, its spread over pairs."""
    through_pair = base_T_flange @ _thesis_transform(x) @ sensor_T_target
    grid = np.einsum("kij,nj->kni", through_pair[:, :3, :3], THESIS_GRID_MM)
    grid += through_pair[:, None, :3, 3]
    return float(np.linalg.norm(grid.std(axis=0)))


def calibrate_thesis(
    base_T_flange: np.ndarray, sensor_T_target: np.ndarray, *, hops: int = 50, seed: int = 0
) -> HandEye:
    """The thesis's method: basin hopping on ‖σ(Y)‖_F from the identity."""
    check_pairs(base_T_flange, sensor_T_target)
    started = time.perf_counter()
    result = optimize.basinhopping(
        thesis_objective,
        np.zeros(6),
        niter=hops,
        stepsize=0.5,
        minimizer_kwargs={"method": "L-BFGS-B", "args": (base_T_flange, sensor_T_target)},
        rng=np.random.default_rng(seed),
    )
    used = np.arange(len(base_T_flange))
    return _finish(
        "thesis",
        base_T_flange,
        sensor_T_target,
        _thesis_transform(result.x),
        None,
        used,
        started,
        details={"objective": float(result.fun), "evaluations": int(result.nfev)},
    )


# --------------------------------------------------------------------------- vista


def park_martin(base_T_flange: np.ndarray, sensor_T_target: np.ndarray) -> np.ndarray:
    """Closed-form X from every pair of poses (i < j): A X = X B with A = F_j⁻¹ F_i and
    B = S_j S_i⁻¹; rotation by Park & Martin (1994), translation by linear least squares."""
    i, j = np.triu_indices(len(base_T_flange), k=1)
    a = invert(base_T_flange[j]) @ base_T_flange[i]
    b = sensor_T_target[j] @ invert(sensor_T_target[i])
    alpha = Rotation.from_matrix(a[:, :3, :3]).as_rotvec()
    beta = Rotation.from_matrix(b[:, :3, :3]).as_rotvec()
    m = beta.T @ alpha
    eigenvalues, eigenvectors = np.linalg.eigh(m.T @ m)
    if eigenvalues.min() <= 1e-12:
        raise CalibrationError("the poses rotate about one axis only: X is not determined")
    inverse_sqrt = eigenvectors @ np.diag(eigenvalues**-0.5) @ eigenvectors.T
    rotation = inverse_sqrt @ m.T
    lhs = (a[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (np.einsum("ij,kj->ki", rotation, b[:, :3, 3]) - a[:, :3, 3]).reshape(-1)
    translation = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return make_transform(rotation, translation)


class _Fit:
    """Weighted least squares over p = [x (6), z (6)] with X = X0 exp(x), Z = Z0 exp(z).

    The residual of pair i is the twist of S_i⁻¹ · (F_i X)⁻¹ Z (measured⁻¹ · predicted plate
    pose) in the target frame. Both noises enter it: the sensor's directly, the robot's
    moved into the target frame by the adjoint of target_T_flange. Each pair's residual is
    whitened by the Cholesky factor of that summed covariance, so a unit residual is one σ.
    """

    def __init__(
        self,
        base_T_flange: np.ndarray,
        sensor_T_target: np.ndarray,
        start_X: np.ndarray,
        start_Z: np.ndarray,
        noise: NoiseModel,
    ) -> None:
        self.F_inv, self.S_inv = invert(base_T_flange), invert(sensor_T_target)
        self.X0, self.Z0 = start_X, start_Z
        robot = np.diag(
            np.repeat([np.radians(noise.robot_sigma_deg), noise.robot_sigma_mm], 3) ** 2
        )
        sensor = np.diag(
            np.repeat([np.radians(noise.sensor_sigma_deg), noise.sensor_sigma_mm], 3) ** 2
        )
        robot_in_target = adjoint(invert(self.F_inv @ start_Z))  # target_T_flange
        covariance = robot_in_target @ robot @ np.swapaxes(robot_in_target, 1, 2) + sensor
        self.whiten = np.linalg.inv(np.linalg.cholesky(covariance))

    def transforms(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.X0 @ from_rotvec(p[:3], p[3:6]), self.Z0 @ from_rotvec(p[6:9], p[9:12])

    def pair_residuals(self, p: np.ndarray) -> np.ndarray:
        """(k, 6) whitened residuals."""
        X, Z = self.transforms(p)
        error = self.S_inv @ invert(X) @ self.F_inv @ Z
        rotvec, translation = to_rotvec(error)
        return np.einsum("kij,kj->ki", self.whiten, np.hstack([rotvec, translation]))

    def solve(self) -> optimize.OptimizeResult:
        return optimize.least_squares(
            lambda p: self.pair_residuals(p).ravel(), np.zeros(12), method="lm", xtol=1e-12
        )


def calibrate_vista(
    base_T_flange: np.ndarray,
    sensor_T_target: np.ndarray,
    *,
    noise: NoiseModel | None = None,
    outlier_probability: float = 1e-3,
    min_pairs: int = 6,
) -> HandEye:
    """Closed-form start, noise-weighted joint refinement, bad pairs dropped, uncertainty.

    A pair is dropped when its weighted squared residual exceeds the χ²(6) quantile of
    ``1 - outlier_probability`` and 4× the median pair's; at most until ``min_pairs`` remain.
    """
    noise = noise or NoiseModel()
    check_pairs(base_T_flange, sensor_T_target)
    started = time.perf_counter()
    threshold = float(chi2.ppf(1 - outlier_probability, df=6))
    used = np.arange(len(base_T_flange))
    dropped: list[DroppedPair] = []
    while True:
        F, S = base_T_flange[used], sensor_T_target[used]
        start_X = park_martin(F, S)
        start_Z = mean_transform(F @ start_X @ S)
        fit = _Fit(F, S, start_X, start_Z, noise)
        result = fit.solve()
        per_pair_chi2 = np.sum(result.fun.reshape(len(used), 6) ** 2, axis=1)
        worst = int(np.argmax(per_pair_chi2))
        bad = per_pair_chi2[worst] > max(threshold, 4 * np.median(per_pair_chi2))
        if not bad or len(used) <= min_pairs:
            break
        X, Z = fit.transforms(result.x)
        residual = plate_residuals_mm(F[worst : worst + 1], S[worst : worst + 1], X, Z)[0]
        dropped.append(DroppedPair(int(used[worst]), float(per_pair_chi2[worst]), float(residual)))
        used = np.delete(used, worst)
    X, Z = fit.transforms(result.x)
    sigma_t, sigma_r, variance_factor = _uncertainty(result, len(used))
    return _finish(
        "vista",
        base_T_flange,
        sensor_T_target,
        X,
        Z,
        used,
        started,
        dropped=tuple(dropped),
        sigma_translation_mm=sigma_t,
        sigma_rotation_deg=sigma_r,
        details={
            "variance_factor": variance_factor,
            "pair_chi2": [float(c) for c in per_pair_chi2],
            "chi2_threshold": threshold,
        },
    )


def _uncertainty(result: optimize.OptimizeResult, pairs: int) -> tuple[float, float, float]:
    """1σ of X's translation (mm) and rotation (deg) from the fit's covariance, inflated by
    the variance factor when the residuals are larger than the noise model says."""
    jacobian = result.jac
    dof = max(1, 6 * pairs - jacobian.shape[1])
    variance_factor = float(np.sum(result.fun**2) / dof)
    covariance = np.linalg.pinv(jacobian.T @ jacobian)[:6, :6] * max(1.0, variance_factor)
    sigma_rotation_deg = float(np.degrees(np.sqrt(np.trace(covariance[:3, :3]))))
    sigma_translation_mm = float(np.sqrt(np.trace(covariance[3:, 3:])))
    return sigma_translation_mm, sigma_rotation_deg, variance_factor


def calibrate(
    base_T_flange: np.ndarray,
    sensor_T_target: np.ndarray,
    *,
    method: str = "vista",
    noise: NoiseModel | None = None,
) -> HandEye:
    """Calibrate with any of ``METHODS``; the result keeps the noise it was given."""
    noise = noise or NoiseModel()
    if method == "vista":
        result = calibrate_vista(base_T_flange, sensor_T_target, noise=noise)
    elif method == "thesis":
        result = calibrate_thesis(base_T_flange, sensor_T_target)
    elif method in OPENCV_METHODS:
        result = calibrate_opencv(base_T_flange, sensor_T_target, method)
    else:
        raise CalibrationError(f"unknown method {method!r}; one of {', '.join(METHODS)}")
    return replace(result, noise=noise)
