"""Point clouds as scanners and CloudCompare export them, turned into vista's cloud.

vista keeps clouds as binary little-endian PLY in millimetres (``ply.py``). A file in another
format is recognised by its content (``sniff``), read by a well-kept library — plyfile for
ASCII and big-endian PLY, pypcd4 for PCD, laspy (with lazrs) for LAS/LAZ, pye57 for E57,
NumPy's text reader for XYZ/ASC/PTS — and converted once, at the door:

- units: each format's convention unless the sender says (``units``): metrology exports
  (PLY, XYZ/ASC text) millimetres, survey and robotics formats (PCD, LAS/LAZ, PTS)
  metres; E57 is metres by its standard and cannot be told otherwise;
- organised grids kept where the format has them (a PCD of height > 1, an E57 scan with
  row and column indices, vista's ``comment width/height`` in PLY), unmeasured pixels NaN;
- colour (8 bits a channel; LAS's 16 bits scaled) and intensity kept;
- far-away coordinates (LAS in UTM, hundreds of km) shifted by whole metres so float32
  millimetres keep their precision; the shift is reported.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.lib.pointcloud.ply import PointCloud, grid_shape_of
from services.lib.pointcloud.promises import (
    PromiseRefused,
    ReaderLimits,
    check_grid,
    check_promise,
)

UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4, "ft": 304.8}
FORMAT_UNITS = {
    "ply": "mm",
    "ply-ascii": "mm",
    "ply-big-endian": "mm",
    "xyz": "mm",
    "pts": "m",
    "pcd": "m",
    "las": "m",
    "laz": "m",
    "e57": "m",
}
"""Each format's unit when the sender does not say: what its writers use by convention."""
FORMAT_NAMES = {
    "ply": "PLY (binary little-endian)",
    "ply-ascii": "PLY (ASCII)",
    "ply-big-endian": "PLY (binary big-endian)",
    "xyz": "XYZ/ASC text",
    "pts": "PTS text",
    "pcd": "PCD",
    "las": "LAS",
    "laz": "LAZ",
    "e57": "E57",
}
FAR_MM = 1.0e6
"""Coordinates beyond 1 km are shifted: float32 keeps ~0.06 mm there, 30 mm at 500 km."""
SNIFF_BYTES = 4096


class ScannerFormatError(ValueError):
    """The file is not a cloud vista can read; the message names the format and the problem."""


@dataclass(frozen=True)
class Converted:
    cloud: PointCloud
    """Millimetres, float32, finite except for a grid's unmeasured pixels."""
    format: str
    units: str
    units_given: bool
    """True: the sender named the unit; False: the format's convention was assumed."""
    origin_shift_mm: tuple[float, float, float]
    """Subtracted from every point (zero unless the coordinates were far away)."""
    dropped_points: int
    """Points without finite coordinates in a cloud that has no grid."""

    def meta(self) -> dict:
        return {
            "format": self.format,
            "format_name": FORMAT_NAMES[self.format],
            "units": self.units,
            "units_assumed": not self.units_given,
            "origin_shift_mm": list(self.origin_shift_mm),
            "dropped_points": self.dropped_points,
        }


def sniff(path: Path) -> str | None:
    """The cloud format of a file by its first bytes, or None."""
    with open(path, "rb") as handle:
        head = handle.read(SNIFF_BYTES)
    if head.startswith((b"ply\n", b"ply\r\n")):
        fmt = head.split(b"format", 1)[1].split()[0] if b"format" in head else b""
        return {b"ascii": "ply-ascii", b"binary_big_endian": "ply-big-endian"}.get(fmt, "ply")
    if head.startswith(b"LASF"):
        # Point data format id (byte 104): its top bits set mean compressed (LAZ).
        return "laz" if len(head) > 104 and head[104] & 0xC0 else "las"
    if head.startswith(b"ASTM-E57"):
        return "e57"
    text = head.lstrip()
    if text.startswith(b"# .PCD") or text.startswith(b"VERSION") or b"\nFIELDS " in head:
        return "pcd"
    return _sniff_text(head)


def _sniff_text(head: bytes) -> str | None:
    """XYZ: rows of at least three numbers; PTS: a point count, then such rows."""
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        return None
    lines = [line for line in text.splitlines()[:-1] if line.strip() and not _comment(line)]
    if not lines:
        return None
    rows = [line.replace(",", " ").split() for line in lines[:8]]
    if not all(_numbers(row) for row in rows):
        return None
    if len(rows[0]) == 1 and len(rows) > 1 and rows[0][0].isdigit() and len(rows[1]) >= 3:
        return "pts"
    return "xyz" if len(rows[0]) >= 3 else None


def _comment(line: str) -> bool:
    return line.lstrip().startswith(("//", "#"))


def _numbers(words: list[str]) -> bool:
    try:
        [float(w) for w in words]
    except ValueError:
        return False
    return True


def read_cloud(
    path: Path,
    *,
    fmt: str | None = None,
    units: str | None = None,
    limits: ReaderLimits | None = None,
) -> Converted:
    """Any supported cloud file as vista's cloud in millimetres, its header's promise
    checked first (``promises``; ``limits`` from the environment unless given). Raises
    ``ScannerFormatError`` naming what cannot be read."""
    limits = limits or ReaderLimits.from_env()
    fmt = fmt or sniff(path)
    if fmt is None:
        raise ScannerFormatError(
            "is not a point cloud vista reads: PLY (ASCII or binary), PCD, LAS/LAZ, E57, "
            "XYZ/ASC or PTS text"
        )
    if units is not None and units not in UNITS_MM:
        raise ScannerFormatError(f"units {units!r} is not one of {', '.join(UNITS_MM)}")
    if fmt == "e57" and units not in (None, "m"):
        raise ScannerFormatError("an E57 file is in metres by its standard; give no units")
    try:
        check_promise(path, fmt, limits)
        cloud = _READERS[fmt](path, limits)
    except PromiseRefused as exc:
        raise ScannerFormatError(f"is not a {FORMAT_NAMES[fmt]} file vista reads: {exc}") from exc
    except (ScannerFormatError, MemoryError):
        raise
    except Exception as exc:  # a library reading a damaged file: whatever it raises, say so
        reason = str(exc).strip().splitlines()[0][:300] if str(exc).strip() else type(exc).__name__
        raise ScannerFormatError(f"is not a readable {FORMAT_NAMES[fmt]} file: {reason}") from exc
    unit = units or FORMAT_UNITS[fmt]
    return _to_mm(cloud, fmt=fmt, units=unit, units_given=units is not None)


def _to_mm(cloud: _Raw, *, fmt: str, units: str, units_given: bool) -> Converted:
    points = cloud.points * UNITS_MM[units]
    finite = np.isfinite(points).all(axis=1)
    dropped = 0
    if cloud.grid_shape is None and not finite.all():
        dropped = int((~finite).sum())
        points = points[finite]
        cloud = cloud.subset(finite)
        finite = finite[finite]
    if not finite.any():
        raise ScannerFormatError(f"the {FORMAT_NAMES[fmt]} file has no measured points")
    if cloud.grid_shape is not None:
        points[~finite] = np.nan  # a pixel half-measured is unmeasured
    shift = np.zeros(3)
    low, high = np.nanmin(points, axis=0), np.nanmax(points, axis=0)
    if np.abs(np.concatenate([low, high])).max() > FAR_MM:
        shift = np.floor(low / 1000.0) * 1000.0
        points = points - shift
    return Converted(
        cloud=PointCloud(
            points=points.astype(np.float32),
            normals=cloud.normals,
            colors=cloud.colors,
            intensity=cloud.intensity,
            grid_shape=cloud.grid_shape,
        ),
        format=fmt,
        units=units,
        units_given=units_given,
        origin_shift_mm=(float(shift[0]), float(shift[1]), float(shift[2])),
        dropped_points=dropped,
    )


@dataclass(frozen=True)
class _Raw:
    """A cloud as read, in the file's unit (float64 points)."""

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    intensity: np.ndarray | None = None
    grid_shape: tuple[int, int] | None = None

    def subset(self, keep: np.ndarray) -> _Raw:
        pick = lambda a: None if a is None else a[keep]  # noqa: E731
        return _Raw(self.points[keep], pick(self.normals), pick(self.colors), pick(self.intensity))


def _stack(
    columns: dict[str, np.ndarray], names: tuple[str, ...], dtype: str | None = None
) -> np.ndarray | None:
    """The named columns side by side (in their own type unless ``dtype``), or None."""
    if not all(n in columns for n in names):
        return None
    stacked = np.stack([np.asarray(columns[n]) for n in names], axis=1)
    return stacked if dtype is None else stacked.astype(dtype)


def _eight_bit(colors: np.ndarray | None) -> np.ndarray | None:
    """Colour channels as 8 bits: 16-bit channels (LAS, some PLY) scaled down."""
    if colors is None:
        return None
    if colors.dtype.kind == "f":
        scale = 255.0 if colors.max(initial=0.0) <= 1.0 else 1.0
        return np.clip(colors * scale, 0, 255).astype(np.uint8)
    if colors.max(initial=0) > 255:
        return (colors.astype(np.uint32) >> 8).astype(np.uint8)
    return colors.astype(np.uint8)


def _from_columns(columns: dict[str, np.ndarray], *, grid_shape=None) -> _Raw:  # noqa: ANN001
    """A cloud from named columns, whichever names the format's writers use."""
    lowered = {name.lower(): values for name, values in columns.items()}
    for axis in "xyz":
        if axis not in lowered:
            raise ScannerFormatError(f"the points have no '{axis}' coordinate")
    intensity = next(
        (lowered[n] for n in ("intensity", "scalar_intensity", "i") if n in lowered), None
    )
    normals = _stack(lowered, ("nx", "ny", "nz"), "float32")
    if normals is None:
        normals = _stack(lowered, ("normal_x", "normal_y", "normal_z"), "float32")
    colors = _stack(lowered, ("red", "green", "blue"))
    if colors is None:
        colors = _stack(lowered, ("r", "g", "b"))
    points = _stack(lowered, ("x", "y", "z"), "float64")
    if normals is not None and not np.isfinite(normals).all():
        normals = None  # unmeasured pixels' normals: none of the cloud's normals are kept
    return _Raw(
        points=points,  # type: ignore[arg-type]
        normals=normals,
        colors=_eight_bit(colors),
        intensity=None if intensity is None else np.asarray(intensity, dtype=np.float32),
        grid_shape=grid_shape,
    )


def _read_ply(path: Path, limits: ReaderLimits) -> _Raw:
    from plyfile import PlyData, PlyParseError

    fast = _read_ascii_vertices(path)
    if fast is not None:
        return fast
    try:
        ply = PlyData.read(str(path))
    except PlyParseError as exc:
        raise ScannerFormatError(f"is not a readable PLY file: {exc}") from exc
    if "vertex" not in ply:
        raise ScannerFormatError("the PLY file has no 'vertex' element")
    vertices = ply["vertex"].data
    columns = {name: vertices[name] for name in vertices.dtype.names or ()}
    grid = grid_shape_of(list(ply.comments))
    if grid is not None and grid[0] * grid[1] != len(vertices):
        grid = None
    return _from_columns(columns, grid_shape=grid)


def _read_ascii_vertices(path: Path) -> _Raw | None:
    """An ASCII PLY whose first element is its vertices, of numbers only, parsed in one
    pass by NumPy (plyfile reads ASCII a value at a time: 13 s for a million points);
    None for any other PLY, which plyfile reads."""
    with open(path, "rb") as handle:
        header = handle.read(64 * 1024)
        end = header.find(b"end_header\n")
        if end < 0:
            return None
        lines = header[:end].decode("ascii", "replace").splitlines()
        words = [line.split() for line in lines]
        elements = [w for w in words if w and w[0] == "element"]
        if ["format", "ascii", "1.0"] not in words or not elements or elements[0][1] != "vertex":
            return None
        first = words.index(elements[0])
        properties = []
        for w in words[first + 1 :]:
            if not w or w[0] != "property":
                break
            if len(w) != 3:  # a list property: plyfile's
                return None
            properties.append(w[2])
        count = int(elements[0][2]) if elements[0][2].isdigit() else -1
        if count <= 0 or not properties:
            return None
        handle.seek(end + len(b"end_header\n"))
        body = handle.read().split(b"\n", count)
    if len(body) < count:
        raise ScannerFormatError(f"the PLY file holds {len(body)} of its {count} vertices")
    values = np.fromstring(b"\n".join(body[:count]), dtype=np.float64, sep=" ")
    if values.size != count * len(properties):
        raise ScannerFormatError(
            f"the PLY file's {count} vertices do not each hold its {len(properties)} numbers"
        )
    columns = dict(zip(properties, values.reshape(count, -1).T, strict=True))
    _bytes_of_text_colours(columns)
    grid = grid_shape_of([" ".join(w[1:]) for w in words if w and w[0] == "comment"])
    return _from_columns(columns, grid_shape=grid if grid and grid[0] * grid[1] == count else None)


def _read_pcd(path: Path, limits: ReaderLimits) -> _Raw:
    from pypcd4 import PointCloud as Pcd

    pcd = Pcd.from_path(path)
    data = pcd.pc_data
    columns = {name: data[name] for name in data.dtype.names or ()}
    if "rgb" in columns or "rgba" in columns:
        packed = columns.pop("rgb", columns.pop("rgba", None))
        rgb = Pcd.decode_rgb(np.asarray(packed))
        columns.update(red=rgb[:, 0], green=rgb[:, 1], blue=rgb[:, 2])
    height, width = int(pcd.metadata.height), int(pcd.metadata.width)
    grid = (height, width) if height > 1 and height * width == len(data) else None
    return _from_columns(columns, grid_shape=grid)


def _read_las(path: Path, limits: ReaderLimits) -> _Raw:
    import laspy

    las = laspy.read(path)
    columns = {"x": np.asarray(las.x), "y": np.asarray(las.y), "z": np.asarray(las.z)}
    names = set(las.point_format.dimension_names)
    if "intensity" in names:
        columns["intensity"] = np.asarray(las.intensity)
    if {"red", "green", "blue"} <= names:
        columns.update(red=las.red, green=las.green, blue=las.blue)
    return _from_columns({k: np.asarray(v) for k, v in columns.items()})


def _read_e57(path: Path, limits: ReaderLimits) -> _Raw:
    """Every scan in the file's common frame; a single scan with row and column indices
    keeps its grid."""
    import pye57

    e57 = pye57.E57(str(path))
    scans = []
    for index in range(e57.scan_count):
        scan = e57.read_scan(
            index, intensity=True, colors=True, row_column=True, ignore_missing_fields=True
        )
        scans.append(scan)
    if not scans:
        raise ScannerFormatError("the E57 file holds no scans")
    if len(scans) == 1 and "rowIndex" in scans[0] and len(scans[0]["rowIndex"]):
        return _e57_grid(scans[0], limits)
    columns: dict[str, np.ndarray] = {}
    for source, target in _E57_FIELDS.items():
        if all(source in scan for scan in scans):
            columns[target] = np.concatenate([scan[source] for scan in scans])
    return _from_columns(columns)


_E57_FIELDS = {
    "cartesianX": "x",
    "cartesianY": "y",
    "cartesianZ": "z",
    "intensity": "intensity",
    "colorRed": "red",
    "colorGreen": "green",
    "colorBlue": "blue",
}


def _e57_grid(scan: dict, limits: ReaderLimits) -> _Raw:
    rows, cols = scan["rowIndex"].astype(np.int64), scan["columnIndex"].astype(np.int64)
    try:
        shape = check_grid(rows, cols, limits)
    except PromiseRefused as exc:
        raise ScannerFormatError(f"is not an E57 file vista reads: {exc}") from exc
    at = rows * shape[1] + cols
    columns = {}
    for source, target in _E57_FIELDS.items():
        if source in scan:
            values = scan[source]
            fill = np.nan if values.dtype.kind == "f" else 0
            full = np.full(shape[0] * shape[1], fill, dtype=values.dtype)
            full[at] = values
            columns[target] = full
    return _from_columns(columns, grid_shape=shape)


def _bytes_of_text_colours(columns: dict[str, np.ndarray]) -> None:
    """Colour channels written as numbers 0–255 in text, as bytes (in place): read as
    floats, they would pass for 0–1 colours when every channel is 0 or 1."""
    for channel in ("red", "green", "blue"):
        if channel in columns:
            columns[channel] = np.clip(columns[channel], 0, 255).astype(np.uint8)


def _read_text(path: Path, *, pts: bool) -> _Raw:
    """Rows of numbers: x y z, then intensity (4 or 7 columns, PTS's order x y z i r g b),
    colour (6) or colour and normals (9, CloudCompare's order)."""
    values = np.loadtxt(path, comments=("//", "#"), skiprows=1 if pts else 0, ndmin=2)
    if values.size == 0:
        raise ScannerFormatError("the text file has no rows of numbers")
    width = values.shape[1]
    layouts = {
        3: ("x", "y", "z"),
        4: ("x", "y", "z", "intensity"),
        6: ("x", "y", "z", "red", "green", "blue"),
        7: ("x", "y", "z", "intensity", "red", "green", "blue"),
        9: ("x", "y", "z", "red", "green", "blue", "nx", "ny", "nz"),
    }
    if width not in layouts:
        raise ScannerFormatError(
            f"rows of {width} numbers: vista reads x y z, then intensity (4), colour (6), "
            "intensity and colour (7, as PTS) or colour and normals (9)"
        )
    columns = dict(zip(layouts[width], values.T, strict=True))
    _bytes_of_text_colours(columns)
    return _from_columns(columns)


_READERS = {
    "ply": _read_ply,
    "ply-ascii": _read_ply,
    "ply-big-endian": _read_ply,
    "pcd": _read_pcd,
    "las": _read_las,
    "laz": _read_las,
    "e57": _read_e57,
    "xyz": lambda path, _limits: _read_text(path, pts=False),
    "pts": lambda path, _limits: _read_text(path, pts=True),
}


def load_cloud(path: Path, *, units: str | None = None) -> PointCloud:
    """A cloud file of any supported format in millimetres (vista's own PLY as it is)."""
    from services.lib.pointcloud.ply import read_ply

    if units in (None, "mm") and sniff(path) == "ply":
        return read_ply(path)
    return read_cloud(path, units=units).cloud
