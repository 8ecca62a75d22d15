"""The pinhole camera of the depth service: intrinsics at an image size, scaled with it.

Pixel (u, v) has its centre at integer coordinates (KITTI's convention); the camera frame is
x right, y down, z forward (metres), and depth is z, the distance along the optical axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KITTI_WIDTH, KITTI_HEIGHT = 1242, 375
KITTI_FOCAL_PX = 721.5377
KITTI_CENTRE_PX = (609.5593, 172.854)
KITTI_BASELINE_M = 0.5327
"""Between KITTI's rectified colour cameras 2 and 3."""
KITTI_HEIGHT_M = 1.65
"""The colour cameras' height above the road."""


@dataclass(frozen=True)
class PinholeCamera:
    """A perspective camera known by its intrinsics at an image size (the depth service's:
    a car's colour camera; the odometry service's floor camera is ``FloorCamera``)."""

    width: int
    height: int
    K: np.ndarray
    """(3, 3) float64 intrinsics at (width, height), pixels."""
    baseline_m: float = KITTI_BASELINE_M

    def __post_init__(self) -> None:
        if self.width < 8 or self.height < 8:
            raise ValueError(f"a {self.width} × {self.height} image is too small (≥ 8 × 8)")
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"K must be a finite 3 × 3 matrix with positive focal lengths: {K}")
        object.__setattr__(self, "K", K)

    def resized(self, width: int, height: int) -> PinholeCamera:
        """The same camera for the image resized to (width, height) (pixel centres kept)."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return PinholeCamera(width, height, K, self.baseline_m)

    def rays(self) -> np.ndarray:
        """(height, width, 3) float32 directions with z = 1: a point at depth z along pixel
        (u, v)'s ray is ``z · rays[v, u]``."""
        u = np.arange(self.width, dtype=np.float64)
        v = np.arange(self.height, dtype=np.float64)
        x = (u[None, :] - self.K[0, 2]) / self.K[0, 0]
        y = (v[:, None] - self.K[1, 2]) / self.K[1, 1]
        out = np.ones((self.height, self.width, 3), np.float32)
        out[..., 0] = np.broadcast_to(x, (self.height, self.width))
        out[..., 1] = np.broadcast_to(y, (self.height, self.width))
        return out

    def to_json(self) -> dict:
        return {
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "baseline_m": self.baseline_m,
        }

    @classmethod
    def from_json(cls, data: dict) -> PinholeCamera:
        try:
            return cls(
                int(data["width"]),
                int(data["height"]),
                np.asarray(data["K"], dtype=np.float64),
                float(data.get("baseline_m", KITTI_BASELINE_M)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a camera (width, height, K, baseline_m): {exc}") from None


def kitti_camera() -> PinholeCamera:
    """KITTI's rectified left colour camera (2011_09_26) at 1242 × 375."""
    K = np.array(
        [
            [KITTI_FOCAL_PX, 0.0, KITTI_CENTRE_PX[0]],
            [0.0, KITTI_FOCAL_PX, KITTI_CENTRE_PX[1]],
            [0.0, 0.0, 1.0],
        ]
    )
    return PinholeCamera(KITTI_WIDTH, KITTI_HEIGHT, K)
