"""Building PLY files (good and bad) for tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.lib.pointcloud.ply import PointCloud, write_ply


def plane_grid(height: int = 40, width: int = 50, spacing_mm: float = 0.1) -> PointCloud:
    """An organized scan of the plane z = 0 with the given pixel spacing."""
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32) * spacing_mm
    points = np.stack([cols, rows, np.zeros_like(cols)], axis=-1).reshape(-1, 3)
    return PointCloud(points=points, grid_shape=(height, width))


def ply_bytes(tmp_path: Path, cloud: PointCloud | None = None) -> bytes:
    path = tmp_path / f"cloud-{np.random.randint(1 << 30)}.ply"
    write_ply(path, cloud or plane_grid())
    return path.read_bytes()


def with_nan(cloud: PointCloud, index: int, axis: int = 0) -> PointCloud:
    points = cloud.points.copy()
    points[index, axis] = np.nan
    return PointCloud(points=points)


def empty_cloud_bytes() -> bytes:
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 0\n"
    header += "property float x\nproperty float y\nproperty float z\nend_header\n"
    return header.encode()


def raw_ply(header_lines: list[str], body: bytes = b"") -> bytes:
    """A binary little-endian PLY of ``header_lines`` (between the format line and
    ``end_header``) and ``body``, however wrong either is."""
    header = ["ply", "format binary_little_endian 1.0", *header_lines, "end_header"]
    return ("\n".join(header) + "\n").encode("latin-1") + body


def mesh_bytes(tmp_path: Path) -> bytes:
    """A 4 × 5 grid of the plane as a triangle mesh (two triangles per cell)."""
    cloud = plane_grid(4, 5)
    corners = np.arange(20).reshape(4, 5)[:-1, :-1].ravel()
    faces = np.concatenate(
        [
            np.stack([corners, corners + 1, corners + 5], 1),
            np.stack([corners + 1, corners + 6, corners + 5], 1),
        ]
    )
    path = tmp_path / f"mesh-{np.random.randint(1 << 30)}.ply"
    write_ply(path, PointCloud(points=cloud.points), faces=faces)
    return path.read_bytes()
