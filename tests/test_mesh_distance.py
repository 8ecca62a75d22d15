"""Signed point-to-mesh distance, exact on triangles: against a box's analytic distance,
against an independent brute-force closest point (plane projection or the nearest of three
segments) over every triangle, and with its sign right beside edges and corners."""

from __future__ import annotations

import re

import numpy as np
import pytest

from services.lib.pointcloud.mesh_distance import (
    TriangleMesh,
    closest_on_triangles,
    signed_distance,
)


def box_mesh(half_mm: np.ndarray) -> TriangleMesh:
    """A closed box centred on the origin, its faces' normals outward."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = np.array(
        [
            [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],  # x = -1, x = +1
            [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],  # y = -1, y = +1
            [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],  # z = -1, z = +1
        ]
    )  # fmt: skip
    return TriangleMesh(corners * half_mm, faces)


def box_distance(points: np.ndarray, half: np.ndarray) -> np.ndarray:
    q = np.abs(points) - half
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    inside = np.minimum(q.max(axis=1), 0)
    return outside + inside


def reference_distance(point: np.ndarray, tri: np.ndarray) -> float:
    """The distance from ``point`` to triangle ``tri`` by another route: the plane's foot
    when it falls inside (barycentric), else the nearest of the three edges."""
    a, b, c = tri
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    foot = point - np.dot(point - a, n) * n
    m = np.array([b - a, c - a]).T
    u, v = np.linalg.lstsq(m, foot - a, rcond=None)[0]
    if u >= 0 and v >= 0 and u + v <= 1:
        return float(np.linalg.norm(point - foot))

    def segment(p: np.ndarray, q: np.ndarray) -> float:
        t = np.clip(np.dot(point - p, q - p) / np.dot(q - p, q - p), 0, 1)
        return float(np.linalg.norm(point - (p + t * (q - p))))

    return min(segment(a, b), segment(b, c), segment(c, a))


def test_a_box_is_measured_as_its_analytic_distance_inside_and_out():
    half = np.array([40.0, 25.0, 10.0])
    mesh = box_mesh(half)
    rng = np.random.default_rng(0)
    points = rng.uniform(-80, 80, (20_000, 3))
    found = signed_distance(mesh, points)
    assert np.abs(found.distance_mm - box_distance(points, half)).max() < 1e-9
    on_surface = np.abs(np.abs(found.closest_mm) - half).min(axis=1)
    assert on_surface.max() < 1e-9


def test_the_sign_is_right_beside_edges_and_corners():
    """Outside a corner or an edge, every face normal there may point away from the point:
    the pseudo-normal still says outside (a face's own normal would say inside)."""
    half = np.array([10.0, 10.0, 10.0])
    mesh = box_mesh(half)
    beside = np.array(
        [[10.5, 10.5, 10.5], [10.001, 10.001, 0.0], [-10.2, 0.0, -10.3], [0, 10.4, -10.4]]
    )
    inside = np.array([[9.9, 9.9, 9.9], [9.99, 0.0, -9.99], [0.0, 0.0, 0.0]])
    assert (signed_distance(mesh, beside).distance_mm > 0).all()
    assert (signed_distance(mesh, inside).distance_mm < 0).all()


def test_every_point_gets_its_nearest_triangle_on_an_uneven_mesh():
    """A bumpy open sheet of small and long triangles: the grid's and the hierarchy's
    answers are a brute force's over all faces."""
    rng = np.random.default_rng(3)
    xs, ys = np.sort(rng.uniform(0, 50, 14)), np.sort(rng.uniform(0, 30, 9))
    gx, gy = np.meshgrid(xs, ys)
    gz = 2.0 * np.sin(gx / 7.0) * np.cos(gy / 5.0)
    vertices = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
    cols = len(xs)
    cells = [(r * cols + c) for r in range(len(ys) - 1) for c in range(cols - 1)]
    faces = np.array(
        [[i, i + 1, i + cols + 1] for i in cells] + [[i, i + cols + 1, i + cols] for i in cells]
    )
    mesh = TriangleMesh(vertices, faces)
    far = rng.uniform([-10, -10, -8], [60, 40, 8], (150, 3))
    # and as a scan's points are: within a tenth of a mm of the surface (the grid answers)
    on = vertices[faces[rng.integers(0, len(faces), 150)]].mean(axis=1)
    points = np.vstack([far, on + rng.normal(0, 0.1, on.shape)])
    found = signed_distance(mesh, points)
    brute = np.array([min(reference_distance(p, vertices[f]) for f in faces) for p in points])
    assert np.abs(np.abs(found.distance_mm) - brute).max() < 1e-9
    chosen = np.array(
        [reference_distance(p, vertices[faces[f]]) for p, f in zip(points, found.face, strict=True)]
    )
    assert np.abs(chosen - brute).max() < 1e-9
    # above the sheet (its normals point up) is positive, below negative, away from its border
    inner = (points[:, 0] > xs[0]) & (points[:, 0] < xs[-1]) & (points[:, 1] > ys[0])
    inner &= points[:, 1] < ys[-1]
    above = points[:, 2] > found.closest_mm[:, 2]
    assert (np.sign(found.distance_mm[inner]) == np.where(above[inner], 1, -1)).all()


def test_the_closest_point_regions():
    tri = np.array([[[0.0, 0, 0], [4, 0, 0], [0, 4, 0]]] * 5)
    points = np.array([[1.0, 1, 3], [-1, -1, 0], [5, -1, 0], [2, -2, 1], [3, 3, 0]])
    closest, region = closest_on_triangles(points, tri)
    assert region.tolist() == [0, 1, 2, 4, 5]
    assert closest.tolist() == [[1, 1, 0], [0, 0, 0], [4, 0, 0], [2, 0, 0], [2, 2, 0]]


@pytest.mark.parametrize(
    ("vertices", "faces", "said"),
    [
        (np.zeros((3, 2)), np.array([[0, 1, 2]]), "finite (V, 3)"),
        (np.zeros((3, 3)), np.zeros((0, 3), int), "at least one face"),
        (np.zeros((3, 3)), np.array([[0, 1, 3]]), "outside 0–2"),
    ],
)
def test_a_bad_mesh_is_refused_naming_why(vertices, faces, said):
    with pytest.raises(ValueError, match=re.escape(said)):
        TriangleMesh(vertices, faces)
