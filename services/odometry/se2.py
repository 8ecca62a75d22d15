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
