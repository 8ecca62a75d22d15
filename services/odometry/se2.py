"""Planar rigid motions (x_mm, y_mm, θ_rad), vectorised over rows."""

from __future__ import annotations

import numpy as np


def wrap(theta: np.ndarray) -> np.ndarray:
    """Angles in (−π, π]."""
    return np.pi - np.mod(np.pi - theta, 2 * np.pi)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ∘ b: b (given in a's frame) expressed in a's parent frame; (…, 3) each."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -(c * a[..., 0] + s * a[..., 1])
    y = -(-s * a[..., 0] + c * a[..., 1])
    return np.stack([x, y, wrap(-a[..., 2])], axis=-1)


def relative(poses: np.ndarray) -> np.ndarray:
    """(N−1, 3) motion from each pose to the next, in the frame of the first of the two."""
    return compose(inverse(poses[:-1]), poses[1:])


def integrate(steps: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """(N+1, 3) poses from (N, 3) relative motions, the first at ``start`` (the origin).

    The headings are a running sum; each step's translation is turned by the heading
    before it, so the positions are a running sum too (no loop)."""
    start = np.zeros(3) if start is None else np.asarray(start, float)
    heading = start[2] + np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    dx = c * steps[:, 0] - s * steps[:, 1]
    dy = s * steps[:, 0] + c * steps[:, 1]
    x = start[0] + np.concatenate([[0.0], np.cumsum(dx)])
    y = start[1] + np.concatenate([[0.0], np.cumsum(dy)])
    return np.column_stack([x, y, wrap(heading)])


def pose_covariances(steps: np.ndarray, sigma: np.ndarray, scale_sigma: float = 0.0) -> np.ndarray:
    """(N+1, 3, 3) covariance of each pose ``integrate(steps)`` gives (x, y in mm, θ in rad),
    from (N, 3) independent step errors of standard deviation ``sigma`` (each in its
    step's own frame) and a relative error of the steps' lengths they all share
    (``scale_sigma``).

    First-order propagation through the composition, in closed form: step k's translation
    error turns by the heading before it; its heading error turns every later position
    about the pose after it, so pose n's position moves by ε_θ · J (p_n − p_{k+1}) (J a
    quarter turn); a shared scale error stretches the whole way travelled, s · (p_n − p_0).
    The sums over k < n are running sums (no loop)."""
    poses = integrate(steps)
    count = len(steps)
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    turn = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (N, 2, 2)
    translation = turn @ (np.eye(2) * (sigma[:, :2] ** 2)[:, None, :]) @ turn.transpose(0, 2, 1)
    v = sigma[:, 2] ** 2
    after = poses[1:, :2]  # p_{k+1}

    def running(values: np.ndarray) -> np.ndarray:
        return np.concatenate([np.zeros((1, *values.shape[1:])), np.cumsum(values, axis=0)])

    v_sum = running(v)  # Σ_{k<n} v_k, (N+1,)
    s_sum = running(v[:, None] * after)  # Σ v_k q_k, (N+1, 2)
    m_sum = running(v[:, None, None] * after[:, :, None] * after[:, None, :])  # (N+1, 2, 2)
    p = poses[:, :2]
    outer = (
        v_sum[:, None, None] * p[:, :, None] * p[:, None, :]
        - p[:, :, None] * s_sum[:, None, :]
        - s_sum[:, :, None] * p[:, None, :]
        + m_sum
    )  # Σ v_k (p_n − q_k)(p_n − q_k)ᵀ
    quarter = np.array([[0.0, -1.0], [1.0, 0.0]])
    out = np.zeros((count + 1, 3, 3))
    out[:, :2, :2] = running(translation) + quarter @ outer @ quarter.T
    lever = (v_sum[:, None] * p - s_sum) @ quarter.T  # Σ v_k J (p_n − q_k)
    out[:, :2, 2] = out[:, 2, :2] = lever
    out[:, 2, 2] = v_sum
    travelled = p - p[:1]
    out[:, :2, :2] += scale_sigma**2 * travelled[:, :, None] * travelled[:, None, :]
    return out
