"""A part's nominal (CAD) model read as triangles with its regions: STL (binary, or ASCII
whose ``solid`` blocks are regions), OBJ (``o``/``g`` names), PLY meshes, glTF/GLB (each
mesh node a region, its transform applied), and STEP (each B-rep face a region, its solid's
name first; tessellated by Open CASCADE to a stated chordal tolerance, where
``cadquery-ocp`` is installed).

Lengths: a format that states its unit is read in it (glTF: metres; STEP: its own, given
in mm by Open CASCADE); the others in mm; ``units`` overrides (a file that says otherwise
is wrong more often than the user).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.lib.pointcloud.mesh_distance import TriangleMesh
from services.lib.pointcloud.stl import MAX_TRIANGLES, StlError, read_stl_regions

FORMATS = ("stl", "obj", "ply", "gltf", "glb", "step")
MAX_TEXT_BYTES = 512 * 1024 * 1024
"""OBJ, PLY, glTF and STEP files larger than this are refused before they are read (their
readers hold the whole file); STL is read as it is (its size says its triangle count)."""
STEP_CHORD_MM = 0.01
"""Largest distance between a tessellated STEP face and its exact surface."""
STEP_ANGLE_DEG = 5.0
"""Largest angle between neighbouring triangles' normals on a curved STEP face."""
GLTF_MM = 1000.0
"""glTF's unit is the metre (its specification)."""


class NominalError(ValueError):
    """The file is not a nominal model vista reads; the message says why."""


@dataclass(frozen=True)
class Nominal:
    mesh: TriangleMesh
    region_of_face: np.ndarray
    """(F,) index into ``regions``."""
    regions: tuple[str, ...]
    format: str
    scale_to_mm: float
    """What the file's coordinates were multiplied by."""

    def scaled(self, factor: float) -> Nominal:
        mesh = TriangleMesh(np.asarray(self.mesh.vertices_mm) * factor, self.mesh.faces)
        return Nominal(
            mesh, self.region_of_face, self.regions, self.format, self.scale_to_mm * factor
        )


def format_of(path: Path) -> str:
    """The nominal format a file holds, by its first bytes where they say (a GLB's magic,
    glTF JSON, ISO-10303-21, ply) and by its name's ending otherwise."""
    with path.open("rb") as file:
        head = file.read(512)
    suffix = path.suffix.lower().lstrip(".")
    if head.startswith(b"glTF"):
        return "glb"
    if head.startswith(b"ISO-10303-21"):
        return "step"
    if head.startswith(b"ply"):
        return "ply"
    if head.lstrip().startswith(b"{") and b'"asset"' in head or suffix == "gltf":
        return "gltf"
    if suffix in ("stp", "step"):
        return "step"
    if suffix == "obj" or re.match(rb"\s*(#.*\n\s*)*(v|o|g|mtllib)\s", head):
        return "obj"
    return "stl"


def read_nominal(path: Path, units_mm: float | None = None) -> Nominal:
    """The nominal in ``path``, in mm (``units_mm``: what one of the file's units is in
    mm, overriding what the file says)."""
    kind = format_of(path)
    if kind != "stl" and path.stat().st_size > MAX_TEXT_BYTES:
        raise NominalError(
            f"a {kind.upper()} nominal of {path.stat().st_size / 2**20:.0f} MB: at most "
            f"{MAX_TEXT_BYTES // 2**20} MB are read (an STL may be larger)"
        )
    try:
        mesh, region, names, stated = _READERS[kind](path)
    except (StlError, ValueError, KeyError, IndexError) as exc:
        raise NominalError(f"is not a {kind.upper()} nominal vista reads: {exc}") from exc
    if len(mesh.faces) > MAX_TRIANGLES:
        raise NominalError(f"holds {len(mesh.faces)} triangles; at most {MAX_TRIANGLES} are read")
    nominal = Nominal(mesh, region, names, kind, 1.0)
    scale = stated if units_mm is None else units_mm
    return nominal.scaled(scale) if scale != 1.0 else nominal


def _stl(path: Path) -> tuple:
    mesh, region, names = read_stl_regions(path)
    return mesh, region, names, 1.0


def _obj(path: Path) -> tuple:
    """Vertices (``v``) and faces (``f``, polygons fanned into triangles, ``v/vt/vn`` and
    negative indices read); each ``o`` or ``g`` name begins a region."""
    text = path.read_text(errors="replace")
    vertices = np.array(
        re.findall(r"^v\s+(\S+)\s+(\S+)\s+(\S+)", text, flags=re.M), dtype=np.float64
    ).reshape(-1, 3)
    names = ["part"]
    triangles, regions = [], []
    current = 0
    for line in re.findall(r"^(?:f|o|g)\s.*$", text, flags=re.M):
        if line[0] in "og":
            name = line[1:].strip() or "part"
            if name not in names:
                names.append(name)
            current = names.index(name)
            continue
        corners = [int(token.split("/")[0]) for token in line.split()[1:]]
        corners = [c - 1 if c > 0 else len(vertices) + c for c in corners]
        for k in range(1, len(corners) - 1):
            triangles.append((corners[0], corners[k], corners[k + 1]))
            regions.append(current)
    if not triangles:
        raise ValueError("it holds no face ('f' line)")
    return _compact(vertices, np.array(triangles), np.array(regions), names) + (1.0,)


def _ply(path: Path) -> tuple:
    import trimesh

    mesh = trimesh.load(path, file_type="ply", force="mesh", process=False)
    if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
        raise ValueError("it holds no faces: a point cloud, not a mesh")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    return (
        TriangleMesh(np.asarray(mesh.vertices, float), faces),
        np.zeros(len(faces), np.int64),
        ("part",),
        1.0,
    )


def _gltf(path: Path) -> tuple:
    import trimesh

    scene = trimesh.load(path, force="scene", process=False)
    vertices, faces, regions, names = [], [], [], []
    offset = 0
    for node in sorted(scene.graph.nodes_geometry):  # by name: the same order each time
        transform, geometry = scene.graph[node]
        mesh = scene.geometry[geometry]
        if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
            continue
        points = np.asarray(mesh.vertices, float) @ transform[:3, :3].T + transform[:3, 3]
        names.append(str(node))
        vertices.append(points)
        faces.append(np.asarray(mesh.faces, np.int64) + offset)
        regions.append(np.full(len(mesh.faces), len(names) - 1))
        offset += len(points)
    if not faces:
        raise ValueError("it holds no triangle mesh")
    mesh = TriangleMesh(np.vstack(vertices), np.vstack(faces))
    return mesh, np.concatenate(regions), tuple(names), GLTF_MM


def _step(path: Path) -> tuple:
    from services.lib.pointcloud.step import read_step

    return read_step(path, chord_mm=STEP_CHORD_MM, angle_deg=STEP_ANGLE_DEG) + (1.0,)


def _compact(vertices: np.ndarray, faces: np.ndarray, region: np.ndarray,
             names: list[str]) -> tuple:  # fmt: skip
    """Only the regions that hold faces, numbered in order."""
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"a face names a vertex outside 1–{len(vertices)}")
    used, region = np.unique(region, return_inverse=True)
    return TriangleMesh(vertices, faces), region.ravel(), tuple(names[i] for i in used)


_READERS = {"stl": _stl, "obj": _obj, "ply": _ply, "gltf": _gltf, "glb": _gltf, "step": _step}
