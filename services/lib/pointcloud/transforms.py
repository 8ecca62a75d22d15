"""Rigid transforms as 4×4 homogeneous matrices named ``a_T_b`` (maps frame b into frame a).

Translations are in millimetres; angles are radians inside, degrees where a person reads
them (``*_deg``). Rotation vectors (axis × angle) are the minimal parameters used by the
solvers.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

RIGID_TOLERANCE = 1e-6
ORTHOGONALITY_TOLERANCE = 1e-4
"""Largest |R Rᵀ − I| accepted from a file (about six printed decimals)."""


class TransformError(ValueError):
    """A matrix that is not a rigid transform; the message says what is wrong."""


def make_transform(rotation: np.ndarray, translation_mm: np.ndarray) -> np.ndarray:
    """rotation : (3, 3) or (K, 3, 3); translation_mm : (3,) or (K, 3) → (4, 4) or (K, 4, 4)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    translation_mm = np.asarray(translation_mm, dtype=np.float64)
    out = np.zeros(rotation.shape[:-2] + (4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation_mm
    out[..., 3, 3] = 1.0
    return out


def from_rotvec(rotvec_rad: np.ndarray, translation_mm: np.ndarray) -> np.ndarray:
    """Transform(s) from rotation vector(s) (radians) and translation(s) (mm)."""
    return make_transform(Rotation.from_rotvec(rotvec_rad).as_matrix(), translation_mm)


def to_rotvec(a_T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotation vector in radians, translation in mm) of one or many transforms."""
    return Rotation.from_matrix(a_T_b[..., :3, :3]).as_rotvec(), a_T_b[..., :3, 3].copy()


def invert(a_T_b: np.ndarray) -> np.ndarray:
    """b_T_a of one (4, 4) or many (K, 4, 4) rigid transforms."""
    rotation_t = np.swapaxes(a_T_b[..., :3, :3], -1, -2)
    translation = -np.einsum("...ij,...j->...i", rotation_t, a_T_b[..., :3, 3])
    return make_transform(rotation_t, translation)


def apply(a_T_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """points_b : (N, 3), mm, in frame b → (N, 3) in frame a, in the points' dtype."""
    rotation = a_T_b[:3, :3].astype(points_b.dtype)
    translation = a_T_b[:3, 3].astype(points_b.dtype)
    return points_b @ rotation.T + translation


def rotation_angle_deg(rotation: np.ndarray) -> np.ndarray:
    """Angle of rotation matrix/matrices, degrees (numerically safe near 0 and 180°)."""
    return np.degrees(np.linalg.norm(Rotation.from_matrix(rotation).as_rotvec(), axis=-1))


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(translation error in mm, rotation error in degrees) between two a_T_b."""
    translation_mm = float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
    rotation_deg = float(rotation_angle_deg(estimate[:3, :3].T @ truth[:3, :3]))
    return translation_mm, rotation_deg


def perturb(
    a_T_b: np.ndarray, sigma_mm: float, sigma_deg: float, rng: np.random.Generator
) -> np.ndarray:
    """a_T_b moved by Gaussian noise expressed in frame b, rotating about b's origin:
    σ per axis of translation (mm) and of rotation (deg)."""
    count = a_T_b.shape[:-2]
    noise = from_rotvec(
        rng.normal(0.0, np.radians(sigma_deg), count + (3,)),
        rng.normal(0.0, sigma_mm, count + (3,)),
    )
    return a_T_b @ noise


def adjoint(a_T_b: np.ndarray) -> np.ndarray:
    """(k, 6, 6) adjoints of (k, 4, 4) transforms: they map twists [ω; v] (rad, mm) expressed in
    frame b to frame a, so covariances move as ``Ad Σ Adᵀ``."""
    rotation, translation = a_T_b[:, :3, :3], a_T_b[:, :3, 3]
    skew = np.zeros_like(rotation)
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = (
        -translation[:, 2],
        translation[:, 1],
        -translation[:, 0],
    )
    skew -= np.swapaxes(skew, 1, 2)
    out = np.zeros((len(a_T_b), 6, 6))
    out[:, :3, :3] = rotation
    out[:, 3:, :3] = skew @ rotation
    out[:, 3:, 3:] = rotation
    return out


def look_at(eye_mm: np.ndarray, target_mm: np.ndarray, up: np.ndarray) -> np.ndarray:
    """world_T_view of a frame at ``eye`` whose +z looks at ``target`` (x right, y down)."""
    z = np.asarray(target_mm, float) - np.asarray(eye_mm, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("up is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_transform(np.stack([x, y, z], axis=1), eye_mm)


def check_rigid(matrix: object, name: str) -> np.ndarray:
    """A 4×4 row-major nested list (or array) as a float64 rigid transform, or TransformError."""
    try:
        array = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TransformError(f"{name}: not a 4×4 matrix of numbers ({exc})") from None
    if array.shape != (4, 4):
        raise TransformError(f"{name}: must be 4×4, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise TransformError(f"{name}: contains NaN or infinity")
    if not np.allclose(array[3], [0, 0, 0, 1], atol=RIGID_TOLERANCE):
        raise TransformError(f"{name}: last row must be [0, 0, 0, 1], got {array[3].tolist()}")
    rotation = array[:3, :3]
    orthogonality = np.abs(rotation @ rotation.T - np.eye(3)).max()
    if orthogonality > ORTHOGONALITY_TOLERANCE or np.linalg.det(rotation) < 0:
        raise TransformError(
            f"{name}: the upper-left 3×3 is not a rotation (orthogonality error "
            f"{orthogonality:.2g}, determinant {np.linalg.det(rotation):.4g})"
        )
    # Rounded file values: snap to the nearest rotation so products stay rigid.
    u, _, vt = np.linalg.svd(rotation)
    return make_transform(u @ vt, array[:3, 3])


def to_json(a_T_b: np.ndarray) -> list[list[float]]:
    """4×4 row-major nested list, as the file formats carry it."""
    return [[float(v) for v in row] for row in a_T_b]


def kabsch(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """target_T_source minimising Σ‖T s − t‖² over paired (K, 3) points (Kabsch; Besl &
    McKay's step)."""
    source_mean, target_mean = source.mean(0), target.mean(0)
    u, _, vt = np.linalg.svd((source - source_mean).T @ (target - target_mean))
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rotation = vt.T @ flip @ u.T
    return make_transform(rotation, target_mean - rotation @ source_mean)
