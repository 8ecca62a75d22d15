"""Binary little-endian PLY: header parsing, validation, reading and writing.

vista's point clouds are ``x y z`` float32 in millimetres with optional ``nx ny nz``,
``red green blue`` (uchar) and ``intensity``. An organized scan records its grid in the
header as ``comment width W`` and ``comment height H`` (``W * H`` vertices, row-major). In an
organized scan a pixel the sensor did not measure has ``x y z`` all NaN; everywhere else
every coordinate must be finite.

Validation never loads the whole file: it maps the vertex block and checks it in chunks,
so a 10 GB cloud is checked in constant memory.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

PLY_MEDIA_TYPE = "application/x-ply"
MAX_HEADER_BYTES = 64 * 1024
CHECK_CHUNK_ROWS = 1 << 20
MAX_COUNT_DIGITS = 18
"""A count of more digits than this (10^18 rows) is larger than any file; refusing it early
also keeps ``int()`` away from Python's 4300-digit limit."""

_SCALAR_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}  # fmt: skip


class PlyError(ValueError):
    """The file is not a PLY vista can use; the message says what and where."""


@dataclass(frozen=True)
class PlyElement:
    name: str
    count: int
    dtype: np.dtype | None
    """Row type for elements of fixed-size properties; None for elements with lists."""
    list_property: tuple[str, str, str] | None = None
    """(count type, item type, name) of the single list property of e.g. ``face``."""


@dataclass(frozen=True)
class PlyHeader:
    elements: tuple[PlyElement, ...]
    comments: tuple[str, ...]
    header_bytes: int
    grid_shape: tuple[int, int] | None
    """(height, width) of an organized scan."""

    def element(self, name: str) -> PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)


@dataclass(frozen=True)
class PlyInfo:
    """What validation learned about a PLY file."""

    vertex_count: int
    valid_count: int
    """Vertices with finite coordinates (fewer than ``vertex_count`` only in a grid)."""
    properties: tuple[str, ...]
    grid_shape: tuple[int, int] | None
    bounds_min_mm: tuple[float, float, float]
    bounds_max_mm: tuple[float, float, float]


@dataclass(frozen=True)
class PointCloud:
    """points : (N, 3) float32, mm. Optional per-point normals (unit), colors, intensity."""

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    intensity: np.ndarray | None = None
    grid_shape: tuple[int, int] | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"points must be (N, 3), got {self.points.shape}")
        n = len(self.points)
        for name, arr, width in (("normals", self.normals, 3), ("colors", self.colors, 3)):
            if arr is not None and arr.shape != (n, width):
                raise ValueError(f"{name} must be ({n}, {width}), got {arr.shape}")
        if self.intensity is not None and self.intensity.shape != (n,):
            raise ValueError(f"intensity must be ({n},), got {self.intensity.shape}")
        if self.grid_shape is not None and self.grid_shape[0] * self.grid_shape[1] != n:
            raise ValueError(f"grid {self.grid_shape} does not hold {n} points")


def _parse_header(handle: BinaryIO) -> PlyHeader:
    fmt, header = parse_any_header(handle)
    if fmt != ["binary_little_endian", "1.0"]:
        raise PlyError(
            f"format {' '.join(fmt)!r} is not supported: vista reads binary_little_endian 1.0"
        )
    return header


def parse_any_header(handle: BinaryIO) -> tuple[list[str], PlyHeader]:
    """The words of a PLY header's ``format`` line and its elements, whatever the format
    (ASCII and big-endian too: their elements' sizes are those of ``_SCALAR_TYPES``)."""
    raw = handle.read(MAX_HEADER_BYTES)
    if not raw.startswith(b"ply\n") and not raw.startswith(b"ply\r\n"):
        raise PlyError("the file does not start with the PLY magic line 'ply'")
    end = raw.find(b"end_header\n")
    if end < 0:
        raise PlyError(f"no 'end_header' line in the first {MAX_HEADER_BYTES // 1024} KiB")
    header_bytes = end + len(b"end_header\n")
    try:
        lines = raw[:end].decode("ascii").splitlines()[1:]
    except UnicodeDecodeError as exc:
        raise PlyError("the PLY header contains non-ASCII bytes") from exc

    elements: list[dict] = []
    comments: list[str] = []
    fmt = None
    for number, line in enumerate(lines, start=2):
        words = line.split()
        if not words:
            continue
        keyword = words[0]
        if keyword == "format":
            fmt = words[1:]
        elif keyword in ("comment", "obj_info"):
            comments.append(line.partition(" ")[2].strip())
        elif keyword == "element":
            elements.append(_element_line(number, line, words, elements))
        elif keyword == "property":
            if not elements:
                raise PlyError(f"header line {number}: property before any element")
            _add_property(number, line, words, elements[-1])
        else:
            raise PlyError(f"header line {number}: unknown keyword {keyword[:40]!r}")

    if fmt is None:
        raise PlyError("the PLY header has no 'format' line")

    parsed = tuple(
        PlyElement(
            name=e["name"],
            count=e["count"],
            dtype=np.dtype(e["props"]) if not e["list"] else None,
            list_property=e["list"],
        )
        for e in elements
    )
    return fmt, PlyHeader(
        elements=parsed,
        comments=tuple(comments),
        header_bytes=header_bytes,
        grid_shape=grid_shape_of(comments),
    )


def _element_line(number: int, line: str, words: list[str], elements: list[dict]) -> dict:
    """``element NAME COUNT`` as a new element; a count too long to be real and a second
    element of the same name (which one would the readers take?) are refused."""
    if len(words) != 3 or not words[2].isdigit():
        raise PlyError(f"header line {number}: expected 'element NAME COUNT', got {line[:80]!r}")
    if len(words[2]) > MAX_COUNT_DIGITS:
        raise PlyError(
            f"header line {number}: element '{words[1][:40]}' counts {len(words[2])} digits of "
            "rows, more than any file holds"
        )
    if any(e["name"] == words[1] for e in elements):
        raise PlyError(f"header line {number}: a second element named '{words[1][:40]}'")
    return {"name": words[1], "count": int(words[2]), "props": [], "list": None}


def _add_property(number: int, line: str, words: list[str], element: dict) -> None:
    """``property TYPE NAME`` or ``property list COUNT_TYPE ITEM_TYPE NAME`` added to
    ``element``; refused: unknown types, a list counted by a float (a NaN or fractional
    count has no meaning), a name used twice, a list mixed with other properties."""
    name = words[-1] if len(words) in (3, 5) else ""
    if name and any(n == name for n, _ in element["props"]):
        raise PlyError(
            f"header line {number}: property '{name[:40]}' appears twice in element "
            f"'{element['name'][:40]}'"
        )
    if len(words) == 5 and words[1] == "list":
        if words[2] not in _SCALAR_TYPES or words[3] not in _SCALAR_TYPES:
            raise PlyError(f"header line {number}: unknown list type in {line[:80]!r}")
        if np.dtype(_SCALAR_TYPES[words[2]]).kind not in "iu":
            raise PlyError(
                f"header line {number}: a list's count must be an integer type, not {words[2]!r}"
            )
        if element["list"] or element["props"]:
            raise PlyError(
                f"header line {number}: element '{element['name'][:40]}' mixes a list with "
                "other properties, which vista does not read"
            )
        element["list"] = (words[2], words[3], words[4])
    elif len(words) == 3 and words[1] in _SCALAR_TYPES:
        if element["list"]:
            raise PlyError(f"header line {number}: property after a list property")
        element["props"].append((words[2], _SCALAR_TYPES[words[1]]))
    else:
        raise PlyError(f"header line {number}: cannot read property line {line[:80]!r}")


def grid_shape_of(comments: list[str]) -> tuple[int, int] | None:
    """(height, width) from a header's ``comment width W`` and ``comment height H``."""
    values = {}
    for comment in comments:
        words = comment.split()
        if (
            len(words) == 2
            and words[0] in ("width", "height")
            and words[1].isdigit()
            and len(words[1]) <= MAX_COUNT_DIGITS
        ):
            values[words[0]] = int(words[1])
    if "width" in values and "height" in values:
        return values["height"], values["width"]
    return None


def read_header(path: Path) -> PlyHeader:
    with open(path, "rb") as handle:
        return _parse_header(handle)


def _vertex_element(header: PlyHeader) -> PlyElement:
    if not header.elements or header.elements[0].name != "vertex":
        raise PlyError("the first element must be 'vertex'")
    vertex = header.elements[0]
    if vertex.dtype is None:
        raise PlyError("the vertex element must not have list properties")
    names = vertex.dtype.names or ()
    for axis in ("x", "y", "z"):
        if axis not in names:
            raise PlyError(f"the vertex element has no '{axis}' property")
    return vertex


def _list_block_bytes(mapped: np.ndarray, offset: int, element: PlyElement) -> int:
    """Bytes used by an element of equal-length lists (e.g. triangles), checked vectorised."""
    count_type, item_type, name = element.list_property  # type: ignore[misc]
    if element.count == 0:
        return 0
    count_dtype = np.dtype(_SCALAR_TYPES[count_type])
    item_dtype = np.dtype(_SCALAR_TYPES[item_type])
    if offset + count_dtype.itemsize > len(mapped):
        raise PlyError(f"the file ends before element '{element.name}'")
    first = int(np.frombuffer(mapped, count_dtype, 1, offset)[0])
    if first < 0:
        raise PlyError(f"element '{element.name}' starts with a list of {first} items ('{name}')")
    row = count_dtype.itemsize + first * item_dtype.itemsize
    total = row * element.count
    if offset + total > len(mapped):
        raise PlyError(
            f"the file is truncated: element '{element.name}' needs {total} bytes, "
            f"{len(mapped) - offset} remain"
        )
    rows = np.ndarray(
        (element.count,),
        dtype=np.dtype([("n", count_dtype), ("items", item_dtype, (first,))]),
        buffer=mapped,
        offset=offset,
    )
    if np.any(rows["n"] != first):
        raise PlyError(f"element '{element.name}' has lists of different lengths ('{name}')")
    return total


def validate_ply(path: Path) -> PlyInfo:
    """Check header, element sizes and that every coordinate is finite.

    Raises ``PlyError`` naming the first problem found.
    """
    size = Path(path).stat().st_size
    with open(path, "rb") as handle:
        header = _parse_header(handle)
    vertex = _vertex_element(header)
    if vertex.count == 0:
        raise PlyError("the cloud has no points (element vertex 0)")
    if header.grid_shape and header.grid_shape[0] * header.grid_shape[1] != vertex.count:
        h, w = header.grid_shape
        raise PlyError(f"grid {w} x {h} in the header does not match {vertex.count} vertices")

    mapped = np.memmap(path, dtype=np.uint8, mode="r")
    offset = header.header_bytes
    vertex_bytes = vertex.count * vertex.dtype.itemsize  # type: ignore[union-attr]
    if offset + vertex_bytes > size:
        raise PlyError(
            f"the file is truncated: {vertex.count} vertices need {vertex_bytes} bytes, "
            f"{size - offset} remain"
        )
    vertices = np.ndarray((vertex.count,), dtype=vertex.dtype, buffer=mapped, offset=offset)
    offset += vertex_bytes
    for element in header.elements[1:]:
        if element.dtype is not None:
            offset += element.count * element.dtype.itemsize
            if offset > size:
                raise PlyError(f"the file is truncated inside element '{element.name}'")
        else:
            offset += _list_block_bytes(mapped, offset, element)
    if offset != size:
        raise PlyError(f"the file has {size - offset} bytes after the last element")

    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    valid_count = 0
    for start in range(0, vertex.count, CHECK_CHUNK_ROWS):
        chunk = vertices[start : start + CHECK_CHUNK_ROWS]
        xyz = np.stack([chunk["x"], chunk["y"], chunk["z"]], axis=1).astype(np.float64)
        finite = np.isfinite(xyz).all(axis=1)
        unmeasured = np.isnan(xyz).all(axis=1) if header.grid_shape else np.zeros_like(finite)
        bad = ~finite & ~unmeasured
        if bad.any():
            first = start + int(np.argmax(bad))
            raise PlyError(f"vertex {first} has a non-finite coordinate (NaN or infinity)")
        if finite.any():
            np.minimum(low, xyz[finite].min(axis=0), out=low)
            np.maximum(high, xyz[finite].max(axis=0), out=high)
        valid_count += int(finite.sum())
    del vertices, mapped
    if valid_count == 0:
        raise PlyError("the scan has no measured points (every grid pixel is NaN)")
    return PlyInfo(
        vertex_count=vertex.count,
        valid_count=valid_count,
        properties=tuple(vertex.dtype.names or ()),  # type: ignore[union-attr]
        grid_shape=header.grid_shape,
        bounds_min_mm=(float(low[0]), float(low[1]), float(low[2])),
        bounds_max_mm=(float(high[0]), float(high[1]), float(high[2])),
    )


def _columns(vertices: np.ndarray, names: tuple[str, ...], dtype: str) -> np.ndarray | None:
    available = vertices.dtype.names or ()
    if not all(n in available for n in names):
        return None
    return np.stack([vertices[n] for n in names], axis=1).astype(dtype)


def read_ply(path: Path) -> PointCloud:
    """Read a vertex cloud. Faces and other elements are ignored."""
    with open(path, "rb") as handle:
        header = _parse_header(handle)
        vertex = _vertex_element(header)
        available = os.fstat(handle.fileno()).st_size - header.header_bytes
        if vertex.count * vertex.dtype.itemsize > available:  # type: ignore[union-attr]
            raise PlyError(f"the file is truncated: {vertex.count} vertices in {available} bytes")
        handle.seek(header.header_bytes)
        vertices = np.fromfile(handle, dtype=vertex.dtype, count=vertex.count)
    if len(vertices) != vertex.count:
        raise PlyError(f"the file is truncated: {len(vertices)} of {vertex.count} vertices")
    names = vertices.dtype.names or ()
    known = {"x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "intensity"}
    intensity = vertices["intensity"].astype(np.float32) if "intensity" in names else None
    return PointCloud(
        points=_columns(vertices, ("x", "y", "z"), "float32"),  # type: ignore[arg-type]
        normals=_columns(vertices, ("nx", "ny", "nz"), "float32"),
        colors=_columns(vertices, ("red", "green", "blue"), "uint8"),
        intensity=intensity,
        grid_shape=header.grid_shape,
        extra={n: vertices[n].copy() for n in names if n not in known},
    )


def write_ply(
    path: Path,
    cloud: PointCloud,
    *,
    comments: tuple[str, ...] = (),
    faces: np.ndarray | None = None,
    scalars: dict[str, np.ndarray] | None = None,
) -> None:
    """Write ``cloud`` as binary little-endian PLY (vista's on-disk point cloud); with
    ``faces`` ((M, 3) vertex indices) a triangle mesh; with ``scalars`` a float property
    per point each (a scalar field, as CloudCompare shows it)."""
    fields: list[tuple[str, str]] = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if cloud.normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if cloud.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if cloud.intensity is not None:
        fields += [("intensity", "<f4")]
    fields += [(name, "<f4") for name in scalars or {}]
    rows = np.empty(len(cloud.points), dtype=np.dtype(fields))
    rows["x"], rows["y"], rows["z"] = cloud.points.T
    if cloud.normals is not None:
        rows["nx"], rows["ny"], rows["nz"] = cloud.normals.T
    if cloud.colors is not None:
        rows["red"], rows["green"], rows["blue"] = cloud.colors.T
    if cloud.intensity is not None:
        rows["intensity"] = cloud.intensity
    for name, values in (scalars or {}).items():
        rows[name] = values
    ply_names = {"<f4": "float", "u1": "uchar"}
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in comments]
    if cloud.grid_shape is not None:
        lines += [f"comment width {cloud.grid_shape[1]}", f"comment height {cloud.grid_shape[0]}"]
    lines.append(f"element vertex {len(rows)}")
    lines += [f"property {ply_names[t]} {n}" for n, t in fields]
    if faces is not None:
        lines += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    lines.append("end_header")
    with open(path, "wb") as out:
        out.write(("\n".join(lines) + "\n").encode("ascii"))
        rows.tofile(out)
        if faces is not None:
            triangles = np.empty(len(faces), dtype=_TRIANGLE)
            triangles["n"], triangles["items"] = 3, faces
            triangles.tofile(out)


_TRIANGLE = np.dtype([("n", "u1"), ("items", "<i4", (3,))])


def read_mesh(path: Path) -> tuple[PointCloud, np.ndarray]:
    """A triangle mesh: its vertices and (M, 3) int64 faces (element ``face``, lists of
    three indices each, written by ``write_ply(..., faces=...)``)."""
    cloud = read_ply(path)
    header = read_header(path)
    face = next((e for e in header.elements if e.name == "face"), None)
    if face is None:
        raise PlyError("the file has no 'face' element: it is a point cloud, not a mesh")
    kinds = tuple(_SCALAR_TYPES.get(t) for t in (face.list_property or ())[:2])
    if kinds not in (("u1", "<i4"), ("u1", "<u4")):
        raise PlyError("faces must be 'property list uchar int vertex_indices'")
    offset = header.header_bytes
    for element in header.elements:
        if element is face:
            break
        if element.dtype is None:
            raise PlyError(f"element '{element.name}' before the faces has list properties")
        offset += element.count * element.dtype.itemsize
    if offset + face.count * _TRIANGLE.itemsize > Path(path).stat().st_size:
        raise PlyError(f"the file is truncated: {face.count} faces do not fit after the vertices")
    triangles = np.fromfile(path, dtype=_TRIANGLE, count=face.count, offset=offset)
    if len(triangles) != face.count or np.any(triangles["n"] != 3):
        raise PlyError("faces must all be triangles, and all present")
    faces = triangles["items"].astype(np.int64)
    if faces.size and (faces.min() < 0 or faces.max() >= len(cloud.points)):
        raise PlyError("a face refers to a vertex that does not exist")
    return cloud, faces


def read_ply_sample(path: Path, max_points: int, *, seed: int = 0) -> PointCloud:
    """At most ``max_points`` finite vertices, picked uniformly at random (a fixed
    ``seed`` picks the same ones each time), in file order; reads only those rows."""
    header = read_header(path)
    vertex = _vertex_element(header)
    mapped = np.memmap(
        path, dtype=vertex.dtype, mode="r", offset=header.header_bytes, shape=(vertex.count,)
    )
    if vertex.count > max_points:
        rng = np.random.default_rng(seed)
        rows = mapped[np.sort(rng.choice(vertex.count, size=max_points, replace=False))]
    else:
        rows = np.asarray(mapped).copy()
    del mapped
    points = _columns(rows, ("x", "y", "z"), "float32")
    finite = np.isfinite(points).all(axis=1)
    rows = rows[finite]
    return PointCloud(
        points=points[finite],
        normals=_columns(rows, ("nx", "ny", "nz"), "float32"),
        colors=_columns(rows, ("red", "green", "blue"), "uint8"),
        grid_shape=None,
    )
