from __future__ import annotations

import numpy as np
import pytest

from services.lib.pointcloud.ply import PlyError, PointCloud, read_ply, validate_ply, write_ply
from tests.plyfiles import empty_cloud_bytes, plane_grid, with_nan


def test_round_trip_keeps_every_field(tmp_path):
    rng = np.random.default_rng(1)
    n = 600
    normals = rng.normal(size=(n, 3)).astype(np.float32)
    cloud = PointCloud(
        points=rng.uniform(-500, 500, (n, 3)).astype(np.float32),
        normals=normals / np.linalg.norm(normals, axis=1, keepdims=True),
        colors=rng.integers(0, 256, (n, 3), dtype=np.uint8),
        intensity=rng.uniform(0, 1, n).astype(np.float32),
        grid_shape=(20, 30),
    )
    path = tmp_path / "c.ply"
    write_ply(path, cloud)
    back = read_ply(path)
    np.testing.assert_array_equal(back.points, cloud.points)
    np.testing.assert_array_equal(back.normals, cloud.normals)
    np.testing.assert_array_equal(back.colors, cloud.colors)
    np.testing.assert_array_equal(back.intensity, cloud.intensity)
    assert back.grid_shape == (20, 30)


def test_validation_reports_bounds_and_grid(tmp_path):
    path = tmp_path / "g.ply"
    write_ply(path, plane_grid(40, 50, 0.1))
    info = validate_ply(path)
    assert info.vertex_count == 2000 and info.valid_count == 2000
    assert info.grid_shape == (40, 50)
    assert info.bounds_min_mm == (0.0, 0.0, 0.0)
    assert info.bounds_max_mm == pytest.approx((4.9, 3.9, 0.0), abs=1e-6)


def test_unmeasured_grid_pixels_are_allowed_but_not_counted(tmp_path):
    cloud = plane_grid(10, 10)
    points = cloud.points.copy()
    points[:7] = np.nan
    path = tmp_path / "holes.ply"
    write_ply(path, PointCloud(points=points, grid_shape=(10, 10)))
    assert validate_ply(path).valid_count == 93


def _write_raw(tmp_path, data: bytes):
    path = tmp_path / "raw.ply"
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda data: data[:-5], "truncated"),
        (lambda data: data + b"\x00" * 3, "after the last element"),
        (lambda data: b"\x89PNG garbage" + data, "magic"),
        (lambda data: data.replace(b"binary_little_endian", b"ascii"), "not supported"),
        (lambda data: data.replace(b"end_header\n", b"end_headr\n"), "end_header"),
        (lambda data: data.replace(b"element vertex 2000", b"element vertex 2001"), "grid"),
        (lambda data: data.replace(b"property float z", b"property float w"), "'z'"),
    ],
)
def test_damaged_files_are_refused_with_a_reason(tmp_path, damage, message):
    good = tmp_path / "good.ply"
    write_ply(good, plane_grid(40, 50))
    with pytest.raises(PlyError, match=message):
        validate_ply(_write_raw(tmp_path, damage(good.read_bytes())))


def test_random_bytes_are_refused(tmp_path):
    garbage = np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    with pytest.raises(PlyError):
        validate_ply(_write_raw(tmp_path, garbage))


def test_nan_and_infinity_outside_a_grid_are_refused(tmp_path):
    cloud = plane_grid(10, 10)
    path = tmp_path / "nan.ply"
    write_ply(path, with_nan(cloud, 42, axis=2))
    with pytest.raises(PlyError, match="vertex 42"):
        validate_ply(path)
    points = cloud.points.copy()
    points[7, 0] = np.inf
    write_ply(path, PointCloud(points=points, grid_shape=(10, 10)))
    with pytest.raises(PlyError, match="vertex 7"):
        validate_ply(path)


def test_zero_points_are_refused(tmp_path):
    with pytest.raises(PlyError, match="no points"):
        validate_ply(_write_raw(tmp_path, empty_cloud_bytes()))


def test_triangle_faces_are_accepted(tmp_path):
    header = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
        b"property float x\nproperty float y\nproperty float z\n"
        b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    vertices = np.eye(3, dtype="<f4").tobytes()
    face = bytes([3]) + np.array([0, 1, 2], dtype="<i4").tobytes()
    assert validate_ply(_write_raw(tmp_path, header + vertices + face)).vertex_count == 3
    with pytest.raises(PlyError, match="truncated"):
        validate_ply(_write_raw(tmp_path, header + vertices + face[:-1]))
