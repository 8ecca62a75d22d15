"""STL triangle meshes, binary and ASCII: read into a ``TriangleMesh`` (corners shared by
exact coordinates), written back, and checked — watertight, consistently oriented, its
border, area and bounds — as a nominal model is reported at upload.

A binary STL says its triangle count in its header; a file whose size disagrees is not one
(whatever its first bytes, which some exporters start with ``solid``). A file of more than
``MAX_TRIANGLES`` triangles is refused before it is read, so that a huge upload cannot cost
gigabytes of memory.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.lib.pointcloud.mesh_distance import TriangleMesh

MAX_TRIANGLES = 4_000_000
"""About 200 MB of binary STL. Reading a million triangles took 8 s and at most 410 MB of
the process here (sharing the corners is a sort): four million stay under 2 GB."""
BINARY_HEADER = 80
ASCII_TRIANGLE_BYTES = 80
"""The fewest bytes an ASCII triangle takes (its facet, loop and three vertex lines)."""
BINARY_RECORD = np.dtype(
    [("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")]
)
VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)")
SOLID_END = re.compile(rb"^[ \t]*endsolid[^\n]*$", flags=re.M)
SOLID_NAME = re.compile(rb"^\s*solid[ \t]*([^\n]*)")


class StlError(ValueError):
    """The file is not a readable STL: the message says why."""


@dataclass(frozen=True)
class MeshReport:
    triangles: int
    vertices: int
    watertight: bool
    """Every edge is shared by exactly two triangles."""
    consistently_oriented: bool
    """No edge is walked the same way by both its triangles (normals all out, or all in)."""
    border_edges: int
    degenerate_triangles: int
    area_mm2: float
    bounds_min_mm: tuple[float, float, float]
    bounds_max_mm: tuple[float, float, float]


def read_stl(path: Path, *, max_triangles: int = MAX_TRIANGLES) -> TriangleMesh:
    """The mesh in the STL at ``path`` (binary or ASCII), in the file's units."""
    return read_stl_regions(path, max_triangles=max_triangles)[0]


def read_stl_regions(
    path: Path, *, max_triangles: int = MAX_TRIANGLES
) -> tuple[TriangleMesh, np.ndarray, tuple[str, ...]]:
    """The mesh, each face's region and the regions' names: an ASCII STL's ``solid``
    blocks by their names; a binary STL is one region, ``part``."""
    size = path.stat().st_size
    with path.open("rb") as file:
        head = file.read(BINARY_HEADER + 4)
    if len(head) == BINARY_HEADER + 4:
        (count,) = struct.unpack("<I", head[BINARY_HEADER:])
        if size == BINARY_HEADER + 4 + count * BINARY_RECORD.itemsize:
            _check_count(count, max_triangles)
            records = np.fromfile(path, dtype=BINARY_RECORD, count=count, offset=BINARY_HEADER + 4)
            return _shared(records["corners"]), np.zeros(count, np.int64), ("part",)
    if not head.lstrip().startswith(b"solid"):
        raise StlError(
            "neither a binary STL (its size does not match the triangle count in its header) "
            "nor an ASCII one (it does not begin with 'solid')"
        )
    if size // ASCII_TRIANGLE_BYTES > max_triangles:
        raise StlError(
            f"the ASCII STL of {size} bytes may hold more than {max_triangles} triangles, "
            "the most that are read"
        )
    names, corners, region = [], [], []
    for block in SOLID_END.split(path.read_bytes()):
        if not VERTEX.search(block):
            continue
        named = SOLID_NAME.search(block)
        name = (named.group(1).decode(errors="replace").strip() if named else "") or "part"
        if name not in names:
            names.append(name)
        found = _ascii_corners(block)
        corners.append(found)
        region.append(np.full(len(found), names.index(name)))
    if not corners:
        raise StlError("an ASCII STL lists its triangles' corners in threes; found 0")
    return _shared(np.concatenate(corners)), np.concatenate(region), tuple(names)


def _check_count(count: int, max_triangles: int) -> None:
    if count == 0:
        raise StlError("the STL holds no triangle")
    if count > max_triangles:
        raise StlError(f"the STL holds {count} triangles; at most {max_triangles} are read")


def _ascii_corners(text: bytes) -> np.ndarray:
    found = VERTEX.findall(text)
    if not found or len(found) % 3:
        raise StlError(f"an ASCII STL lists its triangles' corners in threes; found {len(found)}")
    try:
        corners = np.array(found, dtype=np.float64)
    except ValueError as exc:
        raise StlError(f"a corner of the ASCII STL is not three numbers: {exc}") from None
    return corners.reshape(-1, 3, 3)


def _shared(corners: np.ndarray) -> TriangleMesh:
    """Triangles (F, 3, 3) as vertices shared by exact coordinates and faces."""
    if not np.isfinite(corners).all():
        raise StlError("a corner of the STL is not a finite number")
    vertices, index = np.unique(
        corners.reshape(-1, 3).astype(np.float64), axis=0, return_inverse=True
    )
    return TriangleMesh(vertices, index.reshape(-1, 3))


def write_stl(
    path: Path,
    mesh: TriangleMesh,
    *,
    binary: bool = True,
    name: str = "vista",
    region_of_face: np.ndarray | None = None,
    regions: tuple[str, ...] = (),
) -> None:
    """``mesh`` as an STL (binary by default), each facet's normal from its corners; an
    ASCII one with ``regions`` holds one ``solid`` of each region's faces."""
    corners = np.asarray(mesh.vertices_mm, dtype=np.float64)[np.asarray(mesh.faces)]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]
    if binary:
        records = np.zeros(len(corners), dtype=BINARY_RECORD)
        records["normal"], records["corners"] = normals, corners
        header = f"{name} (binary STL written by vista)".encode()[:BINARY_HEADER]
        with path.open("wb") as file:
            file.write(header.ljust(BINARY_HEADER, b" "))
            file.write(struct.pack("<I", len(records)))
            records.tofile(file)
        return
    if region_of_face is None or len(regions) < 2:
        region_of_face, regions = np.zeros(len(corners), np.int64), (name,)
    path.write_text(
        "".join(
            _ascii_solid(corners[region_of_face == k], normals[region_of_face == k], solid)
            for k, solid in enumerate(regions)
        )
    )


def _ascii_solid(corners: np.ndarray, normals: np.ndarray, name: str) -> str:
    vertex = "      vertex %.17g %.17g %.17g\n"
    facet = f"  facet normal %.9g %.9g %.9g\n    outer loop\n{vertex * 3}    endloop\n  endfacet\n"
    values = np.hstack([normals, corners.reshape(-1, 9)]).ravel().tolist()
    return f"solid {name}\n{(facet * len(corners)) % tuple(values)}endsolid {name}\n"


def mesh_report(mesh: TriangleMesh) -> MeshReport:
    """What a nominal's upload reports: closed or not, oriented or not, its border, area
    and bounds."""
    vertices = np.asarray(mesh.vertices_mm, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    _, uses = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    _, walked = np.unique(directed, axis=0, return_counts=True)
    corners = vertices[faces]
    doubled = np.linalg.norm(
        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
    )
    low, high = vertices[faces.ravel()].min(axis=0), vertices[faces.ravel()].max(axis=0)
    return MeshReport(
        triangles=len(faces),
        vertices=len(np.unique(faces)),
        watertight=bool((uses == 2).all()),
        consistently_oriented=bool((walked == 1).all()),
        border_edges=int((uses == 1).sum()),
        degenerate_triangles=int((doubled <= 1e-12 * max(float(np.ptp(vertices)), 1.0)).sum()),
        area_mm2=float(doubled.sum() / 2),
        bounds_min_mm=tuple(float(v) for v in low),
        bounds_max_mm=tuple(float(v) for v in high),
    )
