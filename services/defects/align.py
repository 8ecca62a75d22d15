"""A scan put into its nominal's frame, three ways, each with its residual and the 1σ of
the six pose parameters:

- **given**: the cloud is already in the part's frame (a robot cell, a calibrated
  stitching); the residual is measured, nothing is moved.
- **best fit**: robust point-to-plane ICP against the mesh (Chen & Medioni), each step's
  residuals weighted by Tukey's biweight at 4.685 robust σ (MAD, annealed from the start's
  misfit down), so points off the nominal by more than a few σ (outliers, a dent, a part
  of the scan the nominal lacks) stop pulling once the fit is close; started from a given pose, or from the principal axes (the cloud's and the
  nominal's centroid and axes matched, each of the four proper sign choices tried). Only
  scan points are matched to the mesh, so nominal areas the scan never covered cost
  nothing. It reports how far it moved the cloud and whether a few points decide a pose
  direction (a best fit never hides a deviation: it says when it may have).
- **reference points** (3-2-1 / RPS): named points of the nominal matched to points
  picked on the scan, the rigid transform of least squares (Kabsch), each pair's residual.

The transform returned is ``nominal_T_cloud`` (maps the cloud into the nominal's frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from services.lib.pointcloud.mesh_distance import MeshIndex, signed_distance
from services.lib.pointcloud.transforms import apply, from_rotvec, invert, kabsch, to_rotvec

FIT_POINTS = 60_000
"""Points a best fit iterates on, and an alignment's residual is measured on (a seeded
even sample)."""
MAX_ITERATIONS = 60
TUKEY_C = 4.685
MIN_SCALE_MM = 0.005
"""The robust σ is not taken below this (a perfect scan must not weight away its noise)."""
DAMPING = 1e-9
"""Added to the fit's information (times its mean diagonal) so that a pose direction the
surface does not fix (a plane's in-plane motion) takes no step."""
MAX_TURN_RAD = np.radians(5.0)
"""The largest turn one step takes."""
ANNEALING = 0.7
ANNEALED_FROM = 99.0
"""Each iteration the smallest σ the weights take shrinks by ``ANNEALING``, from this
percentile of the start's misfits down to ``MIN_SCALE_MM``: far points (a part's end, its edges, whatever few
points fix a direction) pull while the fit is coarse, then only those that agree."""
CONVERGED_MM = 1e-5
"""A step moving no point of the part's extent by more than this ends the fit."""
FEW_POINTS_SHARE = 0.01
AMBIGUOUS_COST = 1.2
"""A second principal-axes start ending within this factor of the best one's cost: the
part's shape cannot tell them apart."""
UNFIXED = 1.0
"""A pose parameter's 1σ (degrees or mm) beyond which the surface does not fix it."""
POSE_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")
UNFIXED_EIGENVALUE = 1e-12
"""An eigenvalue of the fit's information this small against the largest: a direction
the surface does not fix."""
DOMINATED_SHARE = 0.5
"""A pose direction whose information comes more than this share from 1 % of the points is
decided by a few points."""


class AlignError(ValueError):
    """The alignment cannot be made as asked; the message says why."""


@dataclass(frozen=True)
class Alignment:
    method: str
    nominal_T_cloud: np.ndarray
    residual_rms_mm: float
    """RMS of the points' signed distance after alignment: over an even sample of
    ``FIT_POINTS`` (a comparison puts its own, over every point but the strays, with
    ``measured_on``); for reference points, over the pairs."""
    residual_robust_mm: float
    """1.4826 × the median absolute residual: the noise the fit sees."""
    pose_sigma: tuple[float, ...]
    """1σ of (rx, ry, rz in degrees, tx, ty, tz in mm), from the fit's information; zeros
    for a given pose."""
    moved_mm: float = 0.0
    """How far the fit moved the cloud's centroid from where it started."""
    turned_deg: float = 0.0
    """How far it turned the cloud from where it started."""
    inlier_share: float = 1.0
    """Share of the fitted points the final weights kept (weight > 0)."""
    iterations: int = 0
    warnings: tuple[str, ...] = ()
    pairs: list[dict] = field(default_factory=list)
    """Reference points: each pair's name and residual (mm)."""

    def measured_on(self, residual_mm: np.ndarray) -> Alignment:
        """The alignment with its residual measured on ``residual_mm`` (a comparison's
        every point but the strays); reference points keep their pairs'."""
        if self.method == "points" or len(residual_mm) == 0:
            return self
        return replace(
            self, residual_rms_mm=_rms(residual_mm), residual_robust_mm=_robust_scale(residual_mm)
        )

    def document(self) -> dict:
        return {
            "method": self.method,
            "nominal_T_cloud": np.round(self.nominal_T_cloud, 9).tolist(),
            "residual_rms_mm": round(self.residual_rms_mm, 5),
            "residual_robust_mm": round(self.residual_robust_mm, 5),
            "pose_sigma": dict(
                zip(
                    [f"{n}_{'deg' if n[0] == 'r' else 'mm'}" for n in POSE_NAMES],
                    [float(f"{s:.3g}") for s in self.pose_sigma],
                    strict=True,
                )
            ),
            "moved_mm": round(self.moved_mm, 4),
            "turned_deg": round(self.turned_deg, 5),
            "inlier_share": round(self.inlier_share, 4),
            "iterations": self.iterations,
            "warnings": list(self.warnings),
            **({"pairs": self.pairs} if self.pairs else {}),
        }


def given(mesh: MeshIndex, points_mm: np.ndarray, nominal_T_cloud: np.ndarray | None = None,
          *, workers: int = 1) -> Alignment:  # fmt: skip
    """The cloud as it is (or moved by a known ``nominal_T_cloud``): its residual only."""
    pose = np.eye(4) if nominal_T_cloud is None else np.asarray(nominal_T_cloud, float)
    residual = _residuals(mesh, apply(pose, _sample(points_mm)), workers)
    return Alignment("given", pose, _rms(residual), _robust_scale(residual), (0.0,) * 6)


def best_fit(
    mesh: MeshIndex,
    points_mm: np.ndarray,
    start: np.ndarray | None = None,
    *,
    workers: int = 1,
    seed: int = 0,
) -> Alignment:
    """Robust point-to-plane ICP of ``points_mm`` onto ``mesh`` from ``start`` (a
    nominal_T_cloud), or from the principal axes when None."""
    sample = _sample(points_mm, seed)
    if len(sample) < 6:
        raise AlignError(f"a best fit needs at least 6 points, the cloud has {len(sample)}")
    starts = _principal_starts(mesh, sample) if start is None else [np.asarray(start, float)]
    tries = sorted(
        (_icp(mesh, sample, pose, workers, MAX_ITERATIONS // 4) for pose in starts),
        key=lambda fit: fit.cost,
    )
    best = tries[0]
    fit = _icp(mesh, sample, best.pose, workers, MAX_ITERATIONS)
    first = starts[0] if start is not None else best.start
    warnings = list(fit.warnings)
    if len(tries) > 1 and tries[1].cost < AMBIGUOUS_COST * best.cost:
        warnings.append(
            "the part is nearly symmetric: its principal axes fit about as well turned "
            f"{_angle_between(tries[1].pose, best.pose):.0f}° — give a start pose or "
            "reference points"
        )
    unfixed = [name for name, s in zip(POSE_NAMES, fit.sigma, strict=True) if not s < UNFIXED]
    if unfixed:
        warnings.append(
            f"the nominal's surface does not fix the pose along {', '.join(unfixed)} (a "
            "plane slides in itself, a cylinder along and about its axis): fix it by "
            "reference points"
        )
    residual = _residuals(mesh, apply(fit.pose, sample), workers)
    centroid = sample.mean(axis=0)
    moved = float(np.linalg.norm(apply(fit.pose, centroid[None]) - apply(first, centroid[None])))
    turned = _angle_between(fit.pose, first)
    if fit.iterations >= MAX_ITERATIONS:
        warnings.append(f"the fit had not settled after {MAX_ITERATIONS} iterations")
    return Alignment(
        "best-fit",
        fit.pose,
        _rms(residual),
        _robust_scale(residual),
        fit.sigma,
        moved,
        turned,
        fit.inlier_share,
        best.iterations + fit.iterations,
        tuple(warnings),
    )


def reference_points(nominal_points_mm: dict[str, list[float]],
                     scan_points_mm: dict[str, list[float]]) -> Alignment:  # fmt: skip
    """The rigid transform taking the points picked on the scan onto the nominal's named
    points, by least squares (Kabsch): at least three pairs, not on one line."""
    names = [name for name in nominal_points_mm if name in scan_points_mm]
    missing = sorted(set(nominal_points_mm) ^ set(scan_points_mm))
    if missing:
        raise AlignError(f"reference points named on one side only: {', '.join(missing)}")
    if len(names) < 3:
        raise AlignError(f"reference points: at least 3 pairs are needed, {len(names)} given")
    nominal = np.array([nominal_points_mm[n] for n in names], float)
    scan = np.array([scan_points_mm[n] for n in names], float)
    if (
        nominal.shape != (len(names), 3)
        or not np.isfinite(nominal).all()
        or not np.isfinite(scan).all()
    ):
        raise AlignError("reference points are [x, y, z] in mm, finite")  # fmt: skip
    spread = np.linalg.svd(scan - scan.mean(axis=0), compute_uv=False)
    if spread[1] < 1e-3 * max(spread[0], 1e-9):
        raise AlignError("reference points on one line do not fix a rotation about it")
    pose = kabsch(scan, nominal)
    gaps = np.linalg.norm(apply(pose, scan) - nominal, axis=1)
    dof = max(3 * len(names) - 6, 1)
    scale = float(np.sqrt((gaps**2).sum() / dof))
    jacobian = _point_jacobian(apply(pose, scan))
    sigma = _pose_sigma(jacobian.T @ jacobian, scale)
    warnings = []
    if len(names) == 3:
        warnings.append("three pairs fix the pose exactly: no residual tells a wrong pick")
    return Alignment(
        "points",
        pose,
        float(np.sqrt((gaps**2).mean())),
        float(np.median(gaps) * 1.4826),
        sigma,
        warnings=tuple(warnings),
        pairs=[{"name": n, "residual_mm": round(float(g), 4)} for n, g in zip(names, gaps, strict=True)],
    )  # fmt: skip


@dataclass(frozen=True)
class _Fit:
    pose: np.ndarray
    start: np.ndarray
    cost: float
    sigma: tuple[float, ...]
    inlier_share: float
    iterations: int
    warnings: tuple[str, ...]


def _icp(mesh: MeshIndex, sample: np.ndarray, start: np.ndarray, workers: int,
         iterations: int) -> _Fit:  # fmt: skip
    pose = start.copy()
    extent = float(np.linalg.norm(sample.max(axis=0) - sample.min(axis=0)))
    normals = np.empty_like(mesh.face_normals)  # in the mesh's own numbering
    normals[mesh.face_order] = mesh.face_normals
    done, floor_mm = 0, None
    for done in range(1, iterations + 1):  # noqa: B007 (the count is reported)
        moved = apply(pose, sample)
        found = signed_distance(mesh, moved, workers)
        residual = found.distance_mm
        if floor_mm is None:  # annealed from the start's own misfit down to the noise
            floor_mm = float(np.percentile(np.abs(residual), ANNEALED_FROM))
        floor_mm *= ANNEALING
        weight = _tukey(residual, floor_mm)
        jacobian = _plane_jacobian(moved, normals[found.face])
        information = (jacobian * weight[:, None]).T @ jacobian
        # a touch of damping: a direction the surface does not fix stays where it is
        damped = information + DAMPING * np.trace(information) / 6 * np.eye(6)
        step = -np.linalg.solve(damped, jacobian.T @ (weight * residual))
        turn = np.linalg.norm(step[:3])
        if turn > MAX_TURN_RAD:  # far from the answer, the planes' linearisation is not
            step *= MAX_TURN_RAD / turn
        pose = from_rotvec(step[:3], step[3:]) @ pose
        settled = np.linalg.norm(step[:3]) * extent + np.linalg.norm(step[3:]) < CONVERGED_MM
        if settled and floor_mm <= MIN_SCALE_MM:
            break
    moved = apply(pose, sample)
    found = signed_distance(mesh, moved, workers)
    weight = _tukey(found.distance_mm)
    jacobian = _plane_jacobian(moved, normals[found.face])
    information = (jacobian * weight[:, None]).T @ jacobian
    kept = weight > 0
    scale = _robust_scale(found.distance_mm[kept]) if kept.any() else np.inf
    sigma = _pose_sigma(information, scale)
    warnings = _few_points(jacobian, weight, information)
    # the cost compared between starts: the robust loss per point
    cost = float(np.mean(np.minimum(np.abs(found.distance_mm), TUKEY_C * max(scale, MIN_SCALE_MM))))
    return _Fit(pose, start, cost, sigma, float(kept.mean()), done, tuple(warnings))


def _angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two poses' rotations."""
    turn = a[:3, :3] @ b[:3, :3].T
    return float(np.degrees(np.arccos(np.clip((np.trace(turn) - 1) / 2, -1.0, 1.0))))


def _tukey(residual: np.ndarray, floor_mm: float = MIN_SCALE_MM) -> np.ndarray:
    """Tukey's biweight at ``TUKEY_C`` robust σ of the residuals (MAD), σ taken no
    smaller than ``floor_mm``."""
    c = TUKEY_C * max(_robust_scale(residual), MIN_SCALE_MM, floor_mm)
    u = residual / c
    return np.where(np.abs(u) < 1, (1 - u**2) ** 2, 0.0)


def _plane_jacobian(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """d(signed distance)/d(rotation vector, translation) of points moved by a small
    rigid motion, each against its closest face's plane: [p × n, n]."""
    return np.hstack([np.cross(points, normals), normals])


def _point_jacobian(points: np.ndarray) -> np.ndarray:
    """(3K, 6) d(point)/d(rotation vector, translation) at identity: [-[p]×, I]."""
    rows = np.zeros((len(points), 3, 6))
    x, y, z = points.T
    rows[:, 0, 1], rows[:, 0, 2] = z, -y
    rows[:, 1, 0], rows[:, 1, 2] = -z, x
    rows[:, 2, 0], rows[:, 2, 1] = y, -x
    rows[:, :, 3:] = np.eye(3)
    return rows.reshape(-1, 6)


def _pose_sigma(information: np.ndarray, scale_mm: float) -> tuple[float, ...]:
    """1σ of (rx, ry, rz in degrees, tx, ty, tz in mm) from the information matrix of
    unit-σ residuals scaled by ``scale_mm``. Rotation about the origin: its σ mixes into
    the translation's for a part far from the origin, as the parameters do."""
    values, vectors = np.linalg.eigh(information)
    unfixed = values <= UNFIXED_EIGENVALUE * max(float(values.max()), 1e-300)
    weights = np.where(unfixed, 0.0, 1.0 / np.where(unfixed, 1.0, values))
    variance = (vectors**2 * weights).sum(axis=1) * scale_mm**2
    # a parameter that moves along a direction nothing fixes is not known at all
    touched = (vectors[:, unfixed] ** 2).sum(axis=1) > 1e-9
    sigma = np.where(touched, np.inf, np.sqrt(variance))
    sigma[:3] = np.degrees(sigma[:3])
    return tuple(float(s) for s in sigma)


def _few_points(jacobian: np.ndarray, weight: np.ndarray, information: np.ndarray) -> list[str]:
    """Pose directions more than half of whose information comes from 1 % of the points
    (a fit a few points decide may have moved to hide their deviation)."""
    names = POSE_NAMES
    _, directions = np.linalg.eigh(information)
    share = []
    for k in range(6):
        contribution = weight * (jacobian @ directions[:, k]) ** 2
        top = np.sort(contribution)[::-1][: max(1, int(FEW_POINTS_SHARE * len(contribution)))]
        share.append(top.sum() / max(contribution.sum(), 1e-300))
    warnings = []
    for k in np.flatnonzero(np.array(share) > DOMINATED_SHARE):
        leading = names[int(np.argmax(np.abs(directions[:, k])))]
        warnings.append(
            f"{100 * share[k]:.0f} % of what fixes the pose along {leading} comes from 1 % of "
            "the points: the fit there rests on a few points (check their deviation)"
        )
    return warnings


def _principal_starts(mesh: MeshIndex, sample: np.ndarray) -> list[np.ndarray]:
    """The cloud's centroid and principal axes onto the nominal's (area-weighted), one
    pose for each of the four sign choices that keep the axes right-handed."""
    nominal_centre, nominal_axes = _surface_axes(mesh)
    cloud_centre = sample.mean(axis=0)
    _, _, cloud_axes = np.linalg.svd(sample - cloud_centre, full_matrices=False)
    starts = []
    for signs in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
        axes = cloud_axes * np.array(signs)[:, None]
        if np.linalg.det(axes) < 0:
            axes[2] *= -1
        rotation = nominal_axes.T @ axes
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rotation, nominal_centre - rotation @ cloud_centre
        starts.append(pose)
    return starts


def _surface_axes(mesh: MeshIndex) -> tuple[np.ndarray, np.ndarray]:
    """The nominal surface's area-weighted centroid and principal axes (rows)."""
    corners = mesh.corners
    area = 0.5 * np.linalg.norm(
        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
    )
    centroids = corners.mean(axis=1)
    centre = (centroids * area[:, None]).sum(axis=0) / area.sum()
    # second moments of each triangle about the centre (its corners and centroid)
    offsets = np.concatenate([corners - centre, (centroids - centre)[:, None]], axis=1)
    weights = np.repeat(area[:, None] / 4, 4, axis=1).ravel()
    flat = offsets.reshape(-1, 3)
    moment = (flat * weights[:, None]).T @ flat
    _, vectors = np.linalg.eigh(moment)
    axes = vectors[:, ::-1].T
    if np.linalg.det(axes) < 0:
        axes[2] *= -1
    return centre, axes


def _residuals(mesh: MeshIndex, points: np.ndarray, workers: int) -> np.ndarray:
    return signed_distance(mesh, points, workers).distance_mm


def _sample(points: np.ndarray, seed: int = 0) -> np.ndarray:
    """At most ``FIT_POINTS`` of the finite points, an even seeded sample."""
    points = np.asarray(points, dtype=np.float64)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) <= FIT_POINTS:
        return points
    rng = np.random.default_rng(seed)
    return points[np.sort(rng.choice(len(points), FIT_POINTS, replace=False))]


def _robust_scale(residual: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(residual - np.median(residual))))


def _rms(residual: np.ndarray) -> float:
    return float(np.sqrt(np.mean(residual**2)))


def pose_difference(
    estimate: np.ndarray, truth: np.ndarray, at_mm: np.ndarray
) -> tuple[float, float]:
    """(largest displacement in mm of the points ``at_mm`` between the two poses, angle in
    degrees between them): how far an alignment is from the truth where the part is."""
    gap = np.linalg.norm(apply(estimate, at_mm) - apply(truth, at_mm), axis=1).max()
    rotvec, _ = to_rotvec(estimate @ invert(truth))
    return float(gap), float(np.degrees(np.linalg.norm(rotvec)))
