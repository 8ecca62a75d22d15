"""Signed distance from points to a triangle mesh, exact on the triangles (not to their
vertices): each point's closest point on the mesh, the face it lies on, and the distance
signed by the side of the surface the point is on.

The closest point on a triangle is found region by region (Ericson, *Real-Time Collision
Detection*, 5.1.5: the face, one of three edges or one of three vertices), vectorised over
points × candidate triangles. The sign is the angle-weighted pseudo-normal's at that
closest point (Bærentzen & Aanæs 2005: the face's normal on a face, the sum of the two
faces' normals on an edge, the angle-weighted sum of the incident faces' normals at a
vertex), which is correct on a closed, consistently oriented mesh and on an open one away
from its border; positive on the side the faces' normals point to.

Candidates: each point's k nearest triangle centroids. The answer is certified exact when
the k-th centroid is farther than the best distance found plus the largest distance from a
centroid to its triangle's corners (no other triangle can come closer); points that fail
the check are searched again with twice as many candidates, until all pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

FIRST_CANDIDATES = 8
CHUNK_POINTS = 65_536
"""Points per vectorised block (× candidates × 3 doubles stay a few tens of MB)."""


@dataclass(frozen=True)
class TriangleMesh:
    """Vertices (V, 3) in mm and faces (F, 3) of vertex indices, counter-clockwise seen
    from the side the surface faces (its outside)."""

    vertices_mm: np.ndarray
    faces: np.ndarray

    def __post_init__(self) -> None:
        vertices, faces = np.asarray(self.vertices_mm), np.asarray(self.faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.isfinite(vertices).all():
            raise ValueError("a mesh's vertices are finite (V, 3) coordinates")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise ValueError("a mesh has at least one face of three vertex indices")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise ValueError(f"a face names a vertex outside 0–{len(vertices) - 1}")


@dataclass(frozen=True)
class MeshDistance:
    distance_mm: np.ndarray
    """(N,) signed: positive on the side the faces' normals point to."""
    closest_mm: np.ndarray
    """(N, 3) each point's closest point on the mesh."""
    face: np.ndarray
    """(N,) the face the closest point lies on."""


@dataclass(frozen=True)
class _Prepared:
    corners: np.ndarray  # (F, 3, 3) each face's corners
    centroids: cKDTree
    reach_mm: float  # the largest distance from a centroid to its face's corners
    face_normals: np.ndarray  # (F, 3) unit
    edge_normals: np.ndarray  # (F, 3, 3) pseudo-normal of edge ab, bc, ca of each face
    vertex_normals: np.ndarray  # (F, 3, 3) pseudo-normal at corner a, b, c of each face


def signed_distance(mesh: TriangleMesh, points_mm: np.ndarray) -> MeshDistance:
    """Each of ``points_mm`` (N, 3)'s signed distance to ``mesh``, exact on its triangles."""
    points = np.asarray(points_mm, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError("points are (N, 3) coordinates")
    prepared = _prepare(mesh)
    distance = np.empty(len(points))
    closest = np.empty((len(points), 3))
    face = np.empty(len(points), dtype=np.int64)
    for start in range(0, len(points), CHUNK_POINTS):
        block = slice(start, start + CHUNK_POINTS)
        distance[block], closest[block], face[block] = _block(prepared, points[block])
    return MeshDistance(distance, closest, face)


def _prepare(mesh: TriangleMesh) -> _Prepared:
    vertices = np.asarray(mesh.vertices_mm, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    corners = vertices[faces]
    centroids = corners.mean(axis=1)
    reach = float(np.linalg.norm(corners - centroids[:, None, :], axis=2).max())
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    face_normals = cross / np.where(area2 > 0, area2, 1.0)[:, None]
    # edges, each once whatever the faces' orientation: their two faces' normals summed
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, edge_index = np.unique(edges, axis=0, return_inverse=True)
    edge_sum = np.zeros((edge_index.max() + 1, 3))
    np.add.at(edge_sum, edge_index, np.repeat(face_normals, 3, axis=0))
    # corners: the incident faces' normals weighted by the angle each makes there
    vertex_sum = np.zeros((len(vertices), 3))
    weighted = _corner_angles(corners)[:, :, None] * face_normals[:, None, :]
    np.add.at(vertex_sum, faces.ravel(), weighted.reshape(-1, 3))
    return _Prepared(
        corners=corners,
        centroids=cKDTree(centroids),
        reach_mm=reach,
        face_normals=face_normals,
        edge_normals=edge_sum[edge_index.reshape(-1, 3)],
        vertex_normals=vertex_sum[faces],
    )


def _corner_angles(corners: np.ndarray) -> np.ndarray:
    """(F, 3) each face's interior angle at corners a, b, c (radians)."""
    angles = np.empty(corners.shape[:2])
    for k in range(3):
        u = corners[:, (k + 1) % 3] - corners[:, k]
        v = corners[:, (k + 2) % 3] - corners[:, k]
        cos = np.einsum("ij,ij->i", u, v) / np.maximum(
            np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-300
        )
        angles[:, k] = np.arccos(np.clip(cos, -1.0, 1.0))
    return angles


def _block(prepared: _Prepared, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The signed distances, closest points and faces of one block of points."""
    count = len(prepared.corners)
    distance = np.full(len(points), np.inf)
    closest = np.empty((len(points), 3))
    face = np.empty(len(points), dtype=np.int64)
    region = np.empty(len(points), dtype=np.int8)
    open_points = np.arange(len(points))
    k = min(FIRST_CANDIDATES, count)
    while len(open_points):
        reached, candidates = prepared.centroids.query(points[open_points], k=k)
        reached, candidates = (
            reached.reshape(len(open_points), -1),
            candidates.reshape(len(open_points), -1),
        )
        p = points[open_points]
        near, where = closest_on_triangles(
            np.repeat(p, k, axis=0), prepared.corners[candidates.ravel()]
        )
        near = near.reshape(len(p), k, 3)
        squared = np.einsum("ijk,ijk->ij", near - p[:, None, :], near - p[:, None, :])
        squared[~np.isfinite(squared)] = np.inf  # a degenerate face's inside: none
        best = np.argmin(squared, axis=1)
        rows = np.arange(len(p))
        distance[open_points] = np.sqrt(squared[rows, best])
        closest[open_points] = near[rows, best]
        face[open_points] = candidates[rows, best]
        region[open_points] = where.reshape(len(p), k)[rows, best]
        certain = (k == count) | (reached[:, -1] >= distance[open_points] + prepared.reach_mm)
        open_points = open_points[~certain]
        k = min(2 * k, count)
    normal = _pseudo_normal(prepared, face, region)
    side = np.einsum("ij,ij->i", points - closest, normal)
    return np.where(side < 0, -distance, distance), closest, face


def _pseudo_normal(prepared: _Prepared, face: np.ndarray, region: np.ndarray) -> np.ndarray:
    """The pseudo-normal at each closest point: region 0 the face, 1–3 a corner (a, b, c),
    4–6 an edge (ab, bc, ca)."""
    normal = prepared.face_normals[face].copy()
    at_corner = (region >= 1) & (region <= 3)
    normal[at_corner] = prepared.vertex_normals[face[at_corner], region[at_corner] - 1]
    on_edge = region >= 4
    normal[on_edge] = prepared.edge_normals[face[on_edge], region[on_edge] - 4]
    return normal


def closest_on_triangles(points: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point (N, 3)'s closest point on its triangle (N, 3, 3) and where it lies: 0 the
    face's inside, 1–3 corner a, b or c, 4–6 edge ab, bc or ca (Ericson 5.1.5, every
    Voronoi region tested for all points at once)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    ab, ac, ap = b - a, c - a, points - a
    bp, cp = points - b, points - c

    def dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.einsum("ij,ij->i", u, v)

    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    with np.errstate(divide="ignore", invalid="ignore"):
        denominator = va + vb + vc
        v_face = vb / denominator
        w_face = vc / denominator
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    closest = a + v_face[:, None] * ab + w_face[:, None] * ac
    region = np.zeros(len(points), dtype=np.int8)
    # the tests in Ericson's order; a later one applies only where no earlier did
    rules = (
        ((d1 <= 0) & (d2 <= 0), a, 1),
        ((d3 >= 0) & (d4 <= d3), b, 2),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[:, None] * ab, 4),
        ((d6 >= 0) & (d5 <= d6), c, 3),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[:, None] * ac, 6),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + t_bc[:, None] * (c - b), 5),
    )
    decided = np.zeros(len(points), dtype=bool)
    for test, point, code in rules:
        chosen = test & ~decided
        closest[chosen] = point[chosen]
        region[chosen] = code
        decided |= chosen
    return closest, region
