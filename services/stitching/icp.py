"""ICP between scans, and vista's bounded refinement of the kinematic poses (thesis 6.1, Fig. 6.4).

The thesis tried ICP point-to-point (Besl & McKay) and point-to-plane (Chen & Medioni) on
the carbon panels: without an initial transform the scans collapse onto each other; with the
robot's kinematics as the start, point-to-point still slides along the featureless surface.
Both are here, sequentially aligning each scan to the scans placed before it, so that
behaviour can be reproduced and measured.

``bounded`` is vista's refinement: point-to-plane with the kinematic pose as a prior. Each
step weighs the surface residuals against the kinematic covariance (robot repeatability and
the calibration's own uncertainty, for both scans of a pair), so a direction the surface
does not constrain stays where the robot put it; the final correction is then cut back onto
the ellipsoid holding ``bound_probability`` of that covariance. A scan never moves beyond
what the kinematics allow.

A correction is a left-multiplied transform in the base frame (``refined = C @ kinematic``);
steps are twists ``[ω; v]`` (rad, mm) about the scan's centroid, where rotation and
translation are least coupled.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import get_args

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from services.lib.pointcloud.transforms import adjoint, apply, invert, kabsch, make_transform
from services.stitching.kinds import IcpAlgorithm, IcpStart, NoiseModel, StitchParams

METHODS: tuple[str, ...] = get_args(IcpAlgorithm)
STARTS: tuple[str, ...] = get_args(IcpStart)
MIN_CORRESPONDENCES = 100
DEFAULT_NOISE = NoiseModel()


@dataclass(frozen=True)
class IcpConfig:
    method: str = "bounded"
    """point-to-point | point-to-plane | bounded (point-to-plane within the kinematic bound)."""
    start: str = StitchParams.model_fields["icp_start"].default
    """kinematic: start from the robot pose; none: from the previous scan's pose, as ICP on
    two raw sensor-frame scans does when no initial transform is given."""
    max_distance_mm: float = 1.0
    """Correspondences farther apart than this are ignored."""
    iterations: int = 30
    tolerance_mm: float = 1e-3
    """Stop when a step moves no source point by more than this."""
    source_points: int = 20_000
    target_points: int = 400_000
    """Random samples of the moving scan and of the scans already placed."""
    robot_sigma_mm: float = DEFAULT_NOISE.robot_sigma_mm
    robot_sigma_deg: float = DEFAULT_NOISE.robot_sigma_deg
    """The robot's repeatability, 1σ per axis (a stitch takes it from the calibration)."""
    calibration_sigma_mm: float = 0.0
    calibration_sigma_deg: float = 0.0
    """1σ (total over the three axes, as HANDEYE.json reports it) of flange_T_sensor."""
    degenerate_ratio: float = 0.01
    """bounded: motions whose surface information is below this fraction of the best
    constrained one are left to the kinematic prior."""
    bound_probability: float = 0.9973
    """The bound: this much of the kinematic covariance's mass (χ², 6 dof; 3σ in 1-D)."""
    seed: int = 0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"ICP method must be one of {', '.join(METHODS)}; got {self.method!r}")
        if self.start not in STARTS:
            raise ValueError(f"ICP start must be one of {', '.join(STARTS)}; got {self.start!r}")
        if self.method == "bounded" and self.start != "kinematic":
            raise ValueError("the bounded refinement needs the kinematic start")
        if not self.max_distance_mm > 0:
            raise ValueError(f"max_distance_mm must be positive, got {self.max_distance_mm}")
        if not 0 < self.bound_probability < 1:
            raise ValueError(f"bound_probability must be in (0, 1), got {self.bound_probability}")


@dataclass(frozen=True)
class Alignment:
    """How ICP moved one scan away from its start."""

    correction: np.ndarray
    """(4, 4) base-frame correction of the kinematic pose: refined = correction @ kinematic."""
    iterations: int
    correspondences: int
    rmse_mm: float
    moved_mm: float
    """How far the scan's centroid moved from where the kinematics put it."""
    moved_deg: float
    mahalanobis: float | None
    """The applied correction in kinematic σ (√χ², 6 dof); None without a covariance."""
    fitted_mahalanobis: float | None
    """The same for the correction the surface asked for, before any cut."""
    clipped: bool
    """The correction was cut back onto the kinematic bound."""


def kinematic_covariance(flange_T_sensor: np.ndarray, config: IcpConfig) -> np.ndarray:
    """6×6 covariance of a scan pose's error, as a twist [ω; v] in the sensor frame: robot
    noise (per axis, in the flange frame) carried to the sensor, plus the calibration's."""
    robot = np.diag(np.repeat([np.radians(config.robot_sigma_deg), config.robot_sigma_mm], 3) ** 2)
    to_sensor = adjoint(invert(flange_T_sensor)[None])[0]
    calibration = np.diag(
        np.repeat([np.radians(config.calibration_sigma_deg), config.calibration_sigma_mm], 3) ** 2
        / 3.0
    )
    return to_sensor @ robot @ to_sensor.T + calibration


def twist_transform(twist: np.ndarray, centre_mm: np.ndarray) -> np.ndarray:
    """p ↦ R(ω)(p − c) + c + v as a 4×4."""
    rotation = Rotation.from_rotvec(twist[:3]).as_matrix()
    return make_transform(rotation, centre_mm + twist[3:] - rotation @ centre_mm)


def transform_twist(a_T_b: np.ndarray, centre_mm: np.ndarray) -> np.ndarray:
    """The twist about ``centre_mm`` of a transform (inverse of ``twist_transform``)."""
    rotvec = Rotation.from_matrix(a_T_b[:3, :3]).as_rotvec()
    return np.concatenate([rotvec, apply(a_T_b, centre_mm[None])[0] - centre_mm])


def _plane_system(
    source: np.ndarray, target: np.ndarray, normals: np.ndarray, centre_mm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobian (n, 6) and residuals (n,) of n·(p − q) for a twist about the centre."""
    jacobian = np.hstack([np.cross(source - centre_mm, normals), normals])
    residual = np.einsum("ij,ij->i", source - target, normals)
    return jacobian, residual


def _observable(jacobian: np.ndarray, extent_mm: float, degenerate_ratio: float) -> np.ndarray:
    """Projector onto the motions the surface constrains (Zhang, Kaess & Singh 2016): on a
    flat or prismatic part, sliding shows in the residuals only through normal noise, and
    fitting it would move the scan by noise. Rotations are scaled by the scan's extent so
    both kinds of motion are compared in millimetres; the projector is for unscaled twists."""
    scale = np.repeat([extent_mm, 1.0], 3)
    scaled = jacobian / scale
    values, vectors = np.linalg.eigh(scaled.T @ scaled)
    kept = vectors[:, values > degenerate_ratio * values.max()]
    return (kept @ kept.T) * np.outer(1.0 / scale, scale)


def _mad(values: np.ndarray) -> float:
    return float(np.median(np.abs(values - np.median(values))))


def align(
    source: np.ndarray,
    tree: cKDTree,
    target_normals: np.ndarray | None,
    start: np.ndarray,
    config: IcpConfig,
    *,
    covariance: np.ndarray | None = None,
) -> Alignment:
    """Align ``source`` (n, 3 base-frame points at the kinematic pose) to the points in
    ``tree``, starting from the correction ``start``. ``covariance`` (6×6, twist about the
    source centroid, base axes) is the prior and bound of the ``bounded`` method."""
    source = np.asarray(source, dtype=np.float64)
    centre = source.mean(0)
    extent = float(np.linalg.norm(source - centre, axis=1).max())
    information = None if covariance is None else np.linalg.inv(covariance)
    correction = start.copy()
    iterations, count, rmse = 0, 0, float("nan")
    projector, sigma = None, 1.0
    for iterations in range(1, config.iterations + 1):  # noqa: B007 (used after the loop)
        moved = apply(correction, source)
        distance, index = tree.query(moved, distance_upper_bound=config.max_distance_mm)
        matched = np.isfinite(distance)
        count = int(matched.sum())
        if count < MIN_CORRESPONDENCES:
            break
        p, q = moved[matched], tree.data[index[matched]]
        if config.method == "point-to-point":
            rmse = float(np.sqrt(np.mean(distance[matched] ** 2)))
            step = kabsch(p, q)
        else:
            jacobian, residual = _plane_system(p, q, target_normals[index[matched]], centre)
            rmse = float(np.sqrt(np.mean(residual**2)))
            if information is None:
                twist = np.linalg.lstsq(jacobian, -residual, rcond=None)[0]
            else:
                if projector is None:
                    # Fixed from the first step: which motions the surface constrains, and
                    # the residuals' spread (robust), so the steps solve one problem.
                    projector = _observable(jacobian, extent, config.degenerate_ratio)
                    sigma = max(1.4826 * _mad(residual), 1e-4)
                inlier = np.abs(residual - np.median(residual)) < 4.0 * sigma
                weighted = jacobian[inlier] @ projector.T / sigma
                current = transform_twist(correction, centre)
                twist = -np.linalg.solve(
                    weighted.T @ weighted + information,
                    weighted.T @ residual[inlier] / sigma + information @ current,
                )
            step = twist_transform(twist, centre)
        correction = step @ correction
        shift = np.linalg.norm(step[:3, 3] + step[:3, :3] @ centre - centre)
        turn = np.linalg.norm(Rotation.from_matrix(step[:3, :3]).as_rotvec())
        if shift + turn * extent < config.tolerance_mm:
            break
    fitted = mahalanobis = None
    if information is not None:
        twist = transform_twist(correction, centre)
        fitted = mahalanobis = float(np.sqrt(twist @ information @ twist))
        bound = float(np.sqrt(chi2.ppf(config.bound_probability, 6)))
        if fitted > bound:
            correction = twist_transform(twist * bound / fitted, centre)
            mahalanobis = bound
    final = transform_twist(correction, centre)
    return Alignment(
        correction=correction,
        iterations=iterations,
        correspondences=count,
        rmse_mm=rmse,
        moved_mm=float(np.linalg.norm(final[3:])),
        moved_deg=float(np.degrees(np.linalg.norm(final[:3]))),
        mahalanobis=mahalanobis,
        fitted_mahalanobis=fitted,
        clipped=fitted is not None and fitted > mahalanobis,
    )


def refine_poses(
    points: list[np.ndarray],
    normals: list[np.ndarray | None],
    base_T_scan: np.ndarray,
    flange_T_sensor: np.ndarray,
    config: IcpConfig,
    progress: Callable[[int], None] | None = None,
) -> list[Alignment]:
    """Align scans 1…n−1, in order, each to the (already aligned) scans before it; scan 0
    stays at its kinematic pose. ``points`` are base-frame points at the kinematic poses."""
    if config.method != "point-to-point" and any(n is None for n in normals):
        raise ValueError(f"{config.method} ICP needs normals for every scan")
    rng = np.random.default_rng(config.seed)
    per_scan = max(1, config.target_points // len(points))
    sensor_covariance = kinematic_covariance(flange_T_sensor, config)
    identity = np.eye(4)
    alignments = [Alignment(identity, 0, 0, 0.0, 0.0, 0.0, None, None, False)]
    placed, placed_normals = [], []

    def place(i: int, correction: np.ndarray) -> None:
        pick = rng.choice(len(points[i]), min(per_scan, len(points[i])), replace=False)
        placed.append(apply(correction, points[i][pick].astype(np.float64)))
        if normals[i] is not None:
            placed_normals.append(normals[i][pick].astype(np.float64) @ correction[:3, :3].T)

    place(0, identity)
    for i in range(1, len(points)):
        if progress is not None:
            progress(i)
        tree = cKDTree(np.concatenate(placed))
        target_normals = np.concatenate(placed_normals) if placed_normals else None
        pick = rng.choice(len(points[i]), min(config.source_points, len(points[i])), replace=False)
        source = points[i][pick].astype(np.float64)
        covariance = None
        if config.method == "bounded":
            # Both scans of a pair carry the kinematic error: twice the covariance, moved
            # from the sensor frame to base axes about the source centroid.
            centre_T_sensor = base_T_scan[i].copy()
            centre_T_sensor[:3, 3] -= source.mean(0)
            to_centre = adjoint(centre_T_sensor[None])[0]
            covariance = 2.0 * to_centre @ sensor_covariance @ to_centre.T
        if config.start == "kinematic":
            start = identity
        else:
            previous = alignments[i - 1].correction @ base_T_scan[i - 1]
            start = previous @ invert(base_T_scan[i])
        alignment = align(source, tree, target_normals, start, config, covariance=covariance)
        alignments.append(alignment)
        place(i, alignment.correction)
    return alignments
