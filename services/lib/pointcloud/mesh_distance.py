"""Signed distance from points to a triangle mesh, exact on the triangles (not to their
vertices): each point's closest point on the mesh, the face it lies on, and the distance
signed by the side of the surface the point is on.

Each point first looks in its cell of a grid whose cells list the faces within a band of
them (a cell about a typical face, only the cells near the surface kept): if one of those
faces is within the band, no other face can be nearer, and the answer is certain. Points farther from the surface, or in a
cell a huge face reaches, search a bounding-volume hierarchy of the faces (their Z-order
halved down to pairs) nearer box first, skipping every box farther than the best face so
far, starting from the face nearest to the point before (consecutive points of a scan are
neighbours). The closest point on a triangle is found region by region
(Ericson, *Real-Time Collision Detection*, 5.1.5: the face, one of three edges or one of
three vertices). The sign is the angle-weighted pseudo-normal's at that closest point
(Bærentzen & Aanæs 2005: the face's normal on a face, the sum of the two faces' normals on
an edge, the angle-weighted sum of the incident faces' normals at a vertex), which is
correct on a closed, consistently oriented mesh and on an open one away from its border;
positive on the side the faces' normals point to.

The search is compiled (numba) and runs without the GIL: ``workers`` threads share the
points.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit

LEAF_FACES = 2
"""Faces in a leaf of the hierarchy."""
STACK_DEPTH = 128
"""Boxes waiting in one point's descent: twice the depth of a median-split tree of any
size vectors allow."""
GRID_MAX_ENTRIES = 1 << 26
"""Face entries the grid may hold (12 bytes each); a mesh needing more goes without it."""
GRID_CELLS_PER_FACE = 64
"""A face whose reach covers more cells is left to the hierarchy: the coarse cells it
reaches are marked incomplete and their points search the hierarchy."""
COARSE_MAX_CELLS = 1 << 21
"""Cells of the coarse grid that marks where faces left out of the fine one reach."""
BAND_SHARE = 0.3
"""The grid lists in each cell the faces within this share of a cell of it: a point whose
nearest listed face is that near is answered without the hierarchy."""
CELL_SHARE = 1.0
"""A cell's side in typical faces (the median of their boxes' longest sides): 0.5–1.5 and
bands of 0.2–0.5 cells ran within 10 % of each other on a 200 000-face panel; this one
lists the fewest entries for its speed."""


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
class MeshIndex:
    """A mesh made ready for distance queries: its faces in the hierarchy's order, their
    pseudo-normals, the hierarchy's boxes. Build once with :func:`index_mesh` and query as
    often as wanted (an alignment queries the same mesh tens of times)."""

    face_order: np.ndarray  # (F,) original face of each face in hierarchy order
    corners: np.ndarray  # (F, 3, 3) each face's corners, hierarchy order
    face_normals: np.ndarray  # (F, 3) unit
    edge_normals: np.ndarray  # (F, 3, 3) pseudo-normal of edge ab, bc, ca of each face
    vertex_normals: np.ndarray  # (F, 3, 3) pseudo-normal at corner a, b, c of each face
    face_boxes: np.ndarray  # (F, 6) each face's low and high corner
    boxes: np.ndarray  # (B, 6) each box's low and high corner
    box_content: np.ndarray  # (B, 2) a leaf's first face and count; else its first
    # child (the second follows it) and 0
    grid: _Grid


def signed_distance(
    mesh: TriangleMesh | MeshIndex, points_mm: np.ndarray, workers: int = 1
) -> MeshDistance:
    """Each of ``points_mm`` (N, 3)'s signed distance to ``mesh``, exact on its triangles,
    on ``workers`` threads."""
    points = np.ascontiguousarray(points_mm, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError("points are (N, 3) coordinates")
    if not np.isfinite(points).all():
        raise ValueError("points are finite coordinates")
    index = mesh if isinstance(mesh, MeshIndex) else index_mesh(mesh)
    distance = np.empty(len(points))
    closest = np.empty((len(points), 3))
    face = np.empty(len(points), dtype=np.int64)
    grid = index.grid

    def share(part: slice) -> None:
        _nearest(
            points[part], index.corners, index.face_normals, index.edge_normals,
            index.vertex_normals, index.face_boxes, index.boxes, index.box_content,
            grid.origin_mm, grid.cell_mm, grid.band_mm, grid.shape, grid.cells, grid.start,
            grid.faces, grid.coarse, grid.coarse_shape, grid.incomplete, distance[part],
            closest[part], face[part],
        )  # fmt: skip

    bounds = np.linspace(0, len(points), max(1, workers) + 1).astype(int)
    parts = [slice(bounds[i], bounds[i + 1]) for i in range(len(bounds) - 1)]
    if len(parts) == 1:
        share(parts[0])
    else:
        with ThreadPoolExecutor(len(parts)) as pool:
            list(pool.map(share, parts))
    return MeshDistance(distance, closest, index.face_order[face])


def index_mesh(mesh: TriangleMesh) -> MeshIndex:
    """The faces' hierarchy and pseudo-normals."""
    vertices = np.asarray(mesh.vertices_mm, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    corners = vertices[faces]
    normals = face_normals(mesh)
    # edges, each once whatever the faces' orientation: their two faces' normals summed
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, edge_index = np.unique(edges[:, 0] * len(vertices) + edges[:, 1], return_inverse=True)
    edge_sum = np.zeros((edge_index.max() + 1, 3))
    np.add.at(edge_sum, edge_index.ravel(), np.repeat(normals, 3, axis=0))
    # corners: the incident faces' normals weighted by the angle each makes there
    vertex_sum = np.zeros((len(vertices), 3))
    weighted = _corner_angles(corners)[:, :, None] * normals[:, None, :]
    np.add.at(vertex_sum, faces.ravel(), weighted.reshape(-1, 3))
    edge_normals = edge_sum[edge_index.reshape(-1, 3)]
    vertex_normals = vertex_sum[faces]

    order = np.argsort(_morton(corners.mean(axis=1)), kind="stable")
    face_boxes = np.ascontiguousarray(
        np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1)[order]
    )
    boxes, content = _build_hierarchy(face_boxes)
    return MeshIndex(
        face_order=order,
        corners=np.ascontiguousarray(corners[order]),
        face_normals=np.ascontiguousarray(normals[order]),
        edge_normals=np.ascontiguousarray(edge_normals[order]),
        vertex_normals=np.ascontiguousarray(vertex_normals[order]),
        face_boxes=face_boxes,
        boxes=boxes,
        box_content=content,
        grid=_grid(face_boxes),
    )


@dataclass(frozen=True)
class _Grid:
    """Cells over the mesh's box, each listing the faces within ``band_mm`` of it (a
    point in the cell whose nearest listed face is within ``band_mm`` has found its
    nearest face of all). Only the cells near the surface are kept: their numbers
    (``(i × ny + j) × nz + k``) sorted, each with its run of entries. A coarse grid marks
    where a face too large to list reaches: there the list may be incomplete."""

    origin_mm: np.ndarray  # (3,)
    cell_mm: float
    band_mm: float
    shape: np.ndarray  # (3,) cells along x, y, z; zeros: no grid
    cells: np.ndarray  # (C,) int64 the numbers of the cells that list faces, ascending
    start: np.ndarray  # (C + 1,) each cell's first entry
    faces: np.ndarray  # (E,) int32 the listed faces
    coarse: int  # fine cells along a coarse cell's side
    coarse_shape: np.ndarray  # (3,)
    incomplete: np.ndarray  # (coarse cells,) uint8: 1 where a face left out reaches


def _grid(face_boxes: np.ndarray) -> _Grid:
    """A grid whose cell is ``CELL_SHARE`` of the faces' typical size."""
    low, high = face_boxes[:, :3].min(axis=0), face_boxes[:, 3:].max(axis=0)
    typical = float(np.median((face_boxes[:, 3:] - face_boxes[:, :3]).max(axis=1)))
    extent = high - low
    cell = max(CELL_SHARE * typical, float(extent.max()) / 2**20, 1e-6)
    band = BAND_SHARE * cell
    origin = low - band
    shape = np.maximum(np.ceil((extent + 2 * band) / cell).astype(np.int64), 1)
    coarse = max(1, int(np.ceil((np.prod(shape.astype(float)) / COARSE_MAX_CELLS) ** (1 / 3))))
    coarse_shape = -(-shape // coarse)
    incomplete = np.zeros(int(np.prod(coarse_shape)), dtype=np.uint8)
    reach = np.zeros(len(face_boxes), dtype=np.int64)
    args = (face_boxes, origin, cell, band * 1.001, shape)
    _count_grid(*args, coarse, coarse_shape, incomplete, reach)
    if reach.sum() > GRID_MAX_ENTRIES:
        nothing = np.zeros(0, dtype=np.int64)
        return _Grid(origin, cell, band, np.zeros(3, np.int64), nothing, np.zeros(1, np.int64),
                     nothing.astype(np.int32), 1, np.ones(3, np.int64), np.ones(1, np.uint8))  # fmt: skip
    first = np.concatenate([[0], np.cumsum(reach)])
    numbers = np.empty(first[-1], dtype=np.int64)
    faces = np.empty(first[-1], dtype=np.int32)
    _list_grid(*args, first, numbers, faces)
    order = np.argsort(numbers, kind="stable")
    numbers, faces = numbers[order], faces[order]
    new_cell = np.flatnonzero(np.diff(numbers)) + 1
    start = np.concatenate([[0], new_cell, [len(numbers)]]).astype(np.int64)
    cells = numbers[start[:-1]] if len(numbers) else numbers
    return _Grid(origin, cell, band, shape, cells, start, faces, coarse, coarse_shape, incomplete)


def face_normals(mesh: TriangleMesh) -> np.ndarray:
    """(F, 3) each face's unit normal (zero for a face without area)."""
    corners = np.asarray(mesh.vertices_mm, dtype=np.float64)[np.asarray(mesh.faces)]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    return cross / np.where(area2 > 0, area2, 1.0)[:, None]


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


def _morton(points: np.ndarray) -> np.ndarray:
    """Each point's place along a Z-order curve through its 1024³ cell of the points' box
    (its three 10-bit cell indices' bits interleaved)."""
    low, high = points.min(axis=0), points.max(axis=0)
    cells = ((points - low) / np.maximum(high - low, 1e-300) * 1023).astype(np.uint64)
    spread = cells & np.uint64(0x3FF)
    for shift, mask in ((16, 0x30000FF), (8, 0x300F00F), (4, 0x30C30C3), (2, 0x9249249)):
        spread = (spread | (spread << np.uint64(shift))) & np.uint64(mask)
    return (spread[:, 0] << np.uint64(2)) | (spread[:, 1] << np.uint64(1)) | spread[:, 2]


@njit(cache=True, nogil=True)
def _build_hierarchy(face_boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes over the faces (in Z order), each range halved until a leaf holds
    ``LEAF_FACES`` or fewer; a box's two children follow each other."""
    count = face_boxes.shape[0]
    most = 2 * count + 1  # a leaf holds at least one face
    boxes = np.empty((most, 6))
    content = np.zeros((most, 2), dtype=np.int64)
    # (box, first, end) waiting to be split
    pending = np.empty((most, 3), dtype=np.int64)
    pending[0, 0], pending[0, 1], pending[0, 2] = 0, 0, count
    waiting, made = 1, 1
    while waiting > 0:
        waiting -= 1
        box, first, end = pending[waiting, 0], pending[waiting, 1], pending[waiting, 2]
        for axis in range(3):
            boxes[box, axis] = face_boxes[first:end, axis].min()
            boxes[box, 3 + axis] = face_boxes[first:end, 3 + axis].max()
        if end - first <= LEAF_FACES:
            content[box, 0], content[box, 1] = first, end - first
            continue
        middle = (first + end) // 2
        content[box, 0] = made
        pending[waiting, 0], pending[waiting, 1], pending[waiting, 2] = made, first, middle
        pending[waiting + 1, 0], pending[waiting + 1, 1] = made + 1, middle
        pending[waiting + 1, 2] = end
        waiting += 2
        made += 2
    return boxes[:made].copy(), content[:made].copy()


@njit(cache=True, nogil=True, inline="always")
def _cell_span(
    face_boxes: np.ndarray,
    f: int,
    origin: np.ndarray,
    cell: float,
    band: float,
    shape: np.ndarray,
    span: np.ndarray,
) -> int:
    """The cells face ``f``'s box reaches within ``band`` into ``span`` (3, 2): first and
    last along each axis; returns how many."""
    total = 1
    for axis in range(3):
        first = int(np.floor((face_boxes[f, axis] - band - origin[axis]) / cell))
        last = int(np.floor((face_boxes[f, 3 + axis] + band - origin[axis]) / cell))
        span[axis, 0] = min(max(first, 0), shape[axis] - 1)
        span[axis, 1] = min(max(last, 0), shape[axis] - 1)
        total *= span[axis, 1] - span[axis, 0] + 1
    return total


@njit(cache=True, nogil=True)
def _count_grid(face_boxes: np.ndarray, origin: np.ndarray, cell: float, band: float,
                shape: np.ndarray, coarse: int, coarse_shape: np.ndarray,
                incomplete: np.ndarray, reach: np.ndarray) -> None:  # fmt: skip
    """Each face's number of cells (0 for a face left out, whose coarse cells are marked)."""
    span = np.empty((3, 2), dtype=np.int64)
    for f in range(face_boxes.shape[0]):
        count = _cell_span(face_boxes, f, origin, cell, band, shape, span)
        if count <= GRID_CELLS_PER_FACE:
            reach[f] = count
            continue
        for i in range(span[0, 0] // coarse, span[0, 1] // coarse + 1):
            for j in range(span[1, 0] // coarse, span[1, 1] // coarse + 1):
                for k in range(span[2, 0] // coarse, span[2, 1] // coarse + 1):
                    incomplete[(i * coarse_shape[1] + j) * coarse_shape[2] + k] = 1


@njit(cache=True, nogil=True)
def _list_grid(face_boxes: np.ndarray, origin: np.ndarray, cell: float, band: float,
               shape: np.ndarray, first: np.ndarray, numbers: np.ndarray,
               faces: np.ndarray) -> None:  # fmt: skip
    """Each listed face's entries: (cell number, face), from ``first[f]`` on."""
    span = np.empty((3, 2), dtype=np.int64)
    for f in range(face_boxes.shape[0]):
        if first[f + 1] == first[f]:
            continue
        _cell_span(face_boxes, f, origin, cell, band, shape, span)
        at = first[f]
        for i in range(span[0, 0], span[0, 1] + 1):
            for j in range(span[1, 0], span[1, 1] + 1):
                for k in range(span[2, 0], span[2, 1] + 1):
                    numbers[at] = (i * shape[1] + j) * shape[2] + k
                    faces[at] = f
                    at += 1


@njit(cache=True, nogil=True, inline="always")
def _box_squared(point: np.ndarray, boxes: np.ndarray, box: int) -> float:
    total = 0.0
    for axis in range(3):
        below = boxes[box, axis] - point[axis]
        above = point[axis] - boxes[box, 3 + axis]
        outside = max(below, above, 0.0)
        total += outside * outside
    return total


@njit(cache=True, nogil=True, inline="always")
def _closest_on_triangle(p: np.ndarray, corners: np.ndarray, out: np.ndarray) -> int:
    """The closest point on triangle ``corners`` (3, 3) to ``p`` into ``out`` (3,), and
    where it lies: 0 the face's inside, 1–3 corner a, b or c, 4–6 edge ab, bc or ca
    (Ericson 5.1.5, the Voronoi regions in his order)."""
    a, b, c = corners[0], corners[1], corners[2]
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ap0, ap1, ap2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if d1 <= 0.0 and d2 <= 0.0:
        out[:] = a
        return 1
    bp0, bp1, bp2 = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    if d3 >= 0.0 and d4 <= d3:
        out[:] = b
        return 2
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        out[0], out[1], out[2] = a[0] + t * ab0, a[1] + t * ab1, a[2] + t * ab2
        return 4
    cp0, cp1, cp2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    if d6 >= 0.0 and d5 <= d6:
        out[:] = c
        return 3
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        out[0], out[1], out[2] = a[0] + t * ac0, a[1] + t * ac1, a[2] + t * ac2
        return 6
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out[0], out[1], out[2] = (
            b[0] + t * (c[0] - b[0]),
            b[1] + t * (c[1] - b[1]),
            b[2] + t * (c[2] - b[2]),
        )
        return 5
    total = va + vb + vc
    if total <= 0.0:  # a face without area that no edge test took: its first corner
        out[:] = a
        return 1
    v, w = vb / total, vc / total
    out[0], out[1], out[2] = (
        a[0] + v * ab0 + w * ac0,
        a[1] + v * ab1 + w * ac1,
        a[2] + v * ab2 + w * ac2,
    )
    return 0


@njit(cache=True, nogil=True)
def _nearest(points: np.ndarray, corners: np.ndarray, face_normals: np.ndarray, edge_normals: np.ndarray, vertex_normals: np.ndarray, face_boxes: np.ndarray, boxes: np.ndarray, content: np.ndarray, origin: np.ndarray, cell: float, band: float, shape: np.ndarray, cells: np.ndarray, start: np.ndarray, listed: np.ndarray, coarse: int, coarse_shape: np.ndarray, incomplete: np.ndarray, distance: np.ndarray, closest: np.ndarray, face: np.ndarray) -> None:  # fmt: skip
    stack = np.empty(STACK_DEPTH, dtype=np.int64)
    near = np.empty(3)
    best_point = np.empty(3)
    index = np.empty(3, dtype=np.int64)
    previous = 0
    per_cell = 1.0 / cell
    last_number, last_slot = -1, -1  # the cell looked up for the point before
    for i in range(points.shape[0]):
        p = points[i]
        # the grid's cell first: its faces hold the answer if one is within the band
        inside = shape[0] > 0
        for axis in range(3):
            index[axis] = int(np.floor((p[axis] - origin[axis]) * per_cell)) if inside else -1
            inside = inside and 0 <= index[axis] < shape[axis]
        slot = -1
        if inside:
            wide = ((index[0] // coarse) * coarse_shape[1] + index[1] // coarse) * coarse_shape[2]
            if incomplete[wide + index[2] // coarse] == 0:
                number = (index[0] * shape[1] + index[1]) * shape[2] + index[2]
                if number != last_number:
                    found = np.searchsorted(cells, number)
                    last_number = number
                    last_slot = found if found < len(cells) and cells[found] == number else -1
                slot = last_slot
        # the face nearest to the point before: the first bound to beat
        best_face, best_region = previous, _closest_on_triangle(p, corners[previous], best_point)
        best = (p[0] - best_point[0]) ** 2 + (p[1] - best_point[1]) ** 2
        best += (p[2] - best_point[2]) ** 2
        answered = False
        if slot >= 0:
            for e in range(start[slot], start[slot + 1]):
                f = listed[e]
                if _box_squared(p, face_boxes, f) >= best:
                    continue
                where = _closest_on_triangle(p, corners[f], near)
                squared = (p[0] - near[0]) ** 2 + (p[1] - near[1]) ** 2 + (p[2] - near[2]) ** 2
                if squared < best:
                    best, best_face, best_region = squared, f, where
                    best_point[:] = near
            answered = best <= band * band
        stack[0], waiting = 0, 0 if answered else 1
        while waiting > 0:
            waiting -= 1
            box = stack[waiting]
            if _box_squared(p, boxes, box) >= best:
                continue
            if content[box, 1] > 0:
                for f in range(content[box, 0], content[box, 0] + content[box, 1]):
                    where = _closest_on_triangle(p, corners[f], near)
                    squared = (p[0] - near[0]) ** 2 + (p[1] - near[1]) ** 2 + (p[2] - near[2]) ** 2
                    if squared < best:
                        best, best_face, best_region = squared, f, where
                        best_point[:] = near
                continue
            left = content[box, 0]
            right = left + 1
            to_left, to_right = _box_squared(p, boxes, left), _box_squared(p, boxes, right)
            # the nearer child on top, to be opened first
            if to_left <= to_right:
                if to_right < best:
                    stack[waiting] = right
                    waiting += 1
                if to_left < best:
                    stack[waiting] = left
                    waiting += 1
            else:
                if to_left < best:
                    stack[waiting] = left
                    waiting += 1
                if to_right < best:
                    stack[waiting] = right
                    waiting += 1
        if best_region == 0:
            normal = face_normals[best_face]
        elif best_region <= 3:
            normal = vertex_normals[best_face, best_region - 1]
        else:
            normal = edge_normals[best_face, best_region - 4]
        side = (p[0] - best_point[0]) * normal[0] + (p[1] - best_point[1]) * normal[1]
        side += (p[2] - best_point[2]) * normal[2]
        root = np.sqrt(best)
        distance[i] = -root if side < 0.0 else root
        closest[i] = best_point
        face[i] = best_face
        previous = best_face


@njit(cache=True, nogil=True)
def _closest_each(
    points: np.ndarray, corners: np.ndarray, closest: np.ndarray, region: np.ndarray
) -> None:
    for i in range(points.shape[0]):
        region[i] = _closest_on_triangle(points[i], corners[i], closest[i])


def closest_on_triangles(points: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point (N, 3)'s closest point on its triangle (N, 3, 3) and where it lies: 0 the
    face's inside, 1–3 corner a, b or c, 4–6 edge ab, bc or ca."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    corners = np.ascontiguousarray(corners, dtype=np.float64)
    closest = np.empty_like(points)
    region = np.empty(len(points), dtype=np.int8)
    _closest_each(points, corners, closest, region)
    return closest, region
