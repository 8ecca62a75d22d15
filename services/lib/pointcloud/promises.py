"""What a cloud file's header promises, checked before any reader allocates for it.

A reader believes its header: pypcd4 allocates a PCD's WIDTH × COUNT values, plyfile an
element's count of rows, laspy reads a LAS's VLRs one by one however many it is told, and
an E57 scan's grid is as large as its largest row and column index. A 152-byte PCD that
promised 10 000 000 values a point took 2.8 GB before it was refused, a 4 KB E57 with one
point at index 7999 became a grid of 64 000 000 pixels, a LAS claiming 2³² VLRs kept its
reader busy for 13 minutes (issue 55).

``check_promise`` reads only the header and refuses, naming the number, a promise the
file's size cannot hold (fixed-size records: exactly; text: two bytes a value at least;
compressed data: a ratio no real scan reaches) or one beyond ``ReaderLimits`` — before the
reader runs. ``check_grid`` does the same for a grid built from row and column indices,
against the points that fill it. What the reader then allocates is bounded by the file's
size times a small factor, and the child process it runs in (``reader.py``) is held to a
memory and CPU limit for what no header check foresees.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.lib.pointcloud.ply import PlyError, parse_any_header

MAX_POINTS_DEFAULT = 50_000_000
"""A 0.05 mm scan of a 300 × 200 mm assembly is 24 million points; a LAS tile of a street
tens of millions."""
MAX_RECORD_BYTES = 1024
"""The most bytes one point may take in a PCD or PLY (a PCD's COUNT of 10 000 000 floats
a point is no scanner's)."""
LZF_MAX_RATIO = 64
"""A PCD's ``binary_compressed`` data (LZF) expands at most this much: LZF's own bound is
about 88 (264 bytes from a 3-byte back-reference), real scans 2–4."""
COMPRESSED_POINTS_PER_BYTE = 4
"""LAZ and E57 (bit-packed) spend two bits a point at the very least: real scans 2–8
bytes."""
GRID_FILL = 1 / 16
"""A grid from row and column indices must have at least this share of its pixels
measured (a terrestrial scan's sky leaves half of its grid empty)."""
TEXT_BYTES_PER_VALUE = 2
"""A number in a text file and its separator."""
LAS_VLR_HEADER_BYTES = 54
LAS_EVLR_HEADER_BYTES = 60


@dataclass(frozen=True)
class ReaderLimits:
    """What one cloud reader may take: ``VISTA_MAX_CLOUD_POINTS``,
    ``VISTA_READER_MEMORY_MB``, ``VISTA_READER_CPU_S``, ``VISTA_READERS_AT_ONCE``."""

    max_points: int = MAX_POINTS_DEFAULT
    memory_mb: int = 8192
    """The reader's address space beyond its loaded libraries (RLIMIT_AS): 50 million
    points with colour, read and converted, take about 6 GB."""
    cpu_s: int = 300
    """CPU seconds (RLIMIT_CPU): a 50-million-point LAZ decodes in about a minute."""
    at_once: int = 2
    """Readers running at once on this host; an upload beyond them is answered 429."""

    @classmethod
    def from_env(cls) -> ReaderLimits:
        names = {
            "max_points": "VISTA_MAX_CLOUD_POINTS",
            "memory_mb": "VISTA_READER_MEMORY_MB",
            "cpu_s": "VISTA_READER_CPU_S",
            "at_once": "VISTA_READERS_AT_ONCE",
        }
        values = {}
        for field, name in names.items():
            text = os.environ.get(name)
            if text is None:
                continue
            if not text.strip().isdigit() or int(text) < 1:
                raise ValueError(f"{name}={text!r}: a whole number of at least 1")
            values[field] = int(text)
        return cls(**values)


class PromiseRefused(ValueError):
    """The header promises more than the file holds or than a reader may take."""


def check_promise(path: Path, fmt: str, limits: ReaderLimits) -> None:
    """Raise ``PromiseRefused`` naming the number if ``path``'s header (format ``fmt``, as
    ``scanner.sniff`` names it) promises what its size cannot hold or beyond ``limits``."""
    size = path.stat().st_size
    check = _CHECKS.get(fmt)
    if check is not None:
        check(path, size, limits)


def _points_within(points: int, limits: ReaderLimits, what: str) -> None:
    if points > limits.max_points:
        raise PromiseRefused(
            f"{what} promises {points:,} points, more than this server reads "
            f"(VISTA_MAX_CLOUD_POINTS = {limits.max_points:,})"
        )


def _holds(need: int, have: int, what: str) -> None:
    if need > have:
        raise PromiseRefused(f"{what} needs {need:,} bytes, the file holds {have:,}")


# --- PLY (ASCII and big-endian: vista's own binary PLY is validated in ply.py) ------------


def _ply(path: Path, size: int, limits: ReaderLimits) -> None:
    try:
        with open(path, "rb") as handle:
            fmt, header = parse_any_header(handle)
    except PlyError as exc:
        raise PromiseRefused(str(exc)) from exc
    body = size - header.header_bytes
    ascii_ = fmt[:1] == ["ascii"]
    for element in header.elements:
        what = f"element '{element.name[:40]}' of {element.count:,} rows"
        if element.name == "vertex":
            _points_within(element.count, limits, what)
        if element.dtype is not None:
            if element.dtype.itemsize > MAX_RECORD_BYTES:
                raise PromiseRefused(f"{what} of {element.dtype.itemsize} bytes a row")
            width = len(element.dtype.names or ()) if ascii_ else element.dtype.itemsize
        else:
            width = 1  # a list's count at least
        per_row = width * TEXT_BYTES_PER_VALUE if ascii_ else width
        _holds(element.count * per_row, body, what)


# --- PCD --------------------------------------------------------------------------------


def _pcd_header(path: Path) -> tuple[dict[str, list[str]], int]:
    """The header's lines by keyword, and where its data starts."""
    with open(path, "rb") as handle:
        raw = handle.read(64 * 1024)
    fields: dict[str, list[str]] = {}
    at = 0
    for line in raw.split(b"\n"):
        at += len(line) + 1
        words = line.decode("ascii", "replace").split()
        if not words or words[0].startswith("#"):
            continue
        fields[words[0].upper()] = words[1:]
        if words[0].upper() == "DATA":
            return fields, at
    raise PromiseRefused("the PCD header has no DATA line in its first 64 KiB")


def _whole(words: list[str] | None, what: str, default: list[int] | None = None) -> list[int]:
    if words is None:
        if default is None:
            raise PromiseRefused(f"the PCD header has no {what} line")
        return default
    if not words or not all(w.isdigit() and len(w) <= 18 for w in words):
        raise PromiseRefused(
            f"the PCD header's {what} is not whole numbers: {' '.join(words)[:80]}"
        )
    return [int(w) for w in words]


def _pcd(path: Path, size: int, limits: ReaderLimits) -> None:
    header, start = _pcd_header(path)
    names = header.get("FIELDS", [])
    sizes = _whole(header.get("SIZE"), "SIZE")
    counts = _whole(header.get("COUNT"), "COUNT", [1] * len(sizes))
    if not names or len(sizes) != len(names) or len(counts) != len(names):
        raise PromiseRefused(
            f"the PCD header names {len(names)} fields with {len(sizes)} sizes and "
            f"{len(counts)} counts"
        )
    record = sum(s * c for s, c in zip(sizes, counts, strict=True))
    if record > MAX_RECORD_BYTES or max(counts) > MAX_RECORD_BYTES:
        raise PromiseRefused(
            f"the PCD header promises {record:,} bytes a point (COUNT {' '.join(map(str, counts))})"
            f", more than {MAX_RECORD_BYTES} a scanner's point takes"
        )
    width = _whole(header.get("WIDTH"), "WIDTH")[0]
    height = _whole(header.get("HEIGHT"), "HEIGHT", [1])[0]
    points = _whole(header.get("POINTS"), "POINTS", [width * height])[0]
    if points != width * height:
        raise PromiseRefused(f"the PCD header's POINTS {points:,} is not WIDTH × HEIGHT")
    _points_within(points, limits, "the PCD header")
    body = size - start
    data = (header.get("DATA") or [""])[0].lower()
    what = f"{points:,} points of {record} bytes"
    if data == "ascii":
        _holds(points * sum(counts) * TEXT_BYTES_PER_VALUE - 1, body, what)
    elif data == "binary":
        _holds(points * record, body, what)
    elif data == "binary_compressed":
        with open(path, "rb") as handle:
            handle.seek(start)
            sizes_bytes = handle.read(8)
        if len(sizes_bytes) < 8:
            raise PromiseRefused("the compressed PCD ends before its data's sizes")
        compressed, raw = struct.unpack("<II", sizes_bytes)
        _holds(compressed + 8, body, "the compressed PCD's data")
        if raw != points * record or raw > LZF_MAX_RATIO * max(compressed, 1):
            raise PromiseRefused(
                f"the compressed PCD's {compressed:,} bytes promise {raw:,} ({what}: "
                f"{points * record:,}; LZF expands at most {LZF_MAX_RATIO}×)"
            )


# --- LAS / LAZ --------------------------------------------------------------------------


def _las(path: Path, size: int, limits: ReaderLimits) -> None:
    with open(path, "rb") as handle:
        head = handle.read(375)
    if len(head) < 227:
        raise PromiseRefused(f"the LAS header is {len(head)} bytes, shorter than 227")
    minor = head[25]
    header_size, offset, vlrs = struct.unpack_from("<HII", head, 94)
    point_format, record = head[104], struct.unpack_from("<H", head, 105)[0]
    points = struct.unpack_from("<I", head, 107)[0]
    if minor >= 4 and len(head) >= 255:
        points = max(points, struct.unpack_from("<Q", head, 247)[0])
        evlr_start, evlrs = struct.unpack_from("<QI", head, 235)
        if evlrs:
            _holds(evlr_start + evlrs * LAS_EVLR_HEADER_BYTES, size, f"{evlrs:,} EVLRs")
    if not header_size <= offset <= size:
        raise PromiseRefused(
            f"the LAS points start at byte {offset:,}, outside the file ({size:,} bytes, "
            f"header {header_size})"
        )
    _holds(vlrs * LAS_VLR_HEADER_BYTES, offset - header_size, f"{vlrs:,} VLRs")
    _points_within(points, limits, "the LAS header")
    what = f"{points:,} points of {record} bytes"
    if point_format & 0xC0:  # compressed (LAZ)
        if points > COMPRESSED_POINTS_PER_BYTE * max(size - offset, 0):
            raise PromiseRefused(
                f"the LAZ header promises {points:,} points in {size - offset:,} bytes of "
                f"data (at most {COMPRESSED_POINTS_PER_BYTE} a byte)"
            )
    else:
        _holds(points * record, size - offset, what)


# --- E57 --------------------------------------------------------------------------------


def _e57(path: Path, size: int, limits: ReaderLimits) -> None:
    """The scans' point counts from the XML section (libE57Format reads nothing else)."""
    import pye57

    e57 = pye57.E57(str(path))
    try:
        total = sum(int(e57.get_header(i).point_count) for i in range(e57.scan_count))
    finally:
        e57.close()
    _points_within(total, limits, "the E57 file")
    if total > COMPRESSED_POINTS_PER_BYTE * size:
        raise PromiseRefused(
            f"the E57 file promises {total:,} points in {size:,} bytes "
            f"(at most {COMPRESSED_POINTS_PER_BYTE} a byte)"
        )


def check_grid(rows: np.ndarray, cols: np.ndarray, limits: ReaderLimits) -> tuple[int, int]:
    """The (height, width) of a grid from its points' row and column indices, refused
    where an index is negative, the grid is larger than ``limits`` allow, or its points
    fill less than ``GRID_FILL`` of it."""
    if not len(rows):
        raise PromiseRefused("the scan's grid has no points")
    if rows.min() < 0 or cols.min() < 0:
        raise PromiseRefused("the scan's grid has a negative row or column index")
    shape = (int(rows.max()) + 1, int(cols.max()) + 1)
    cells = shape[0] * shape[1]
    what = f"the scan's grid of {shape[0]:,} × {shape[1]:,} pixels"
    _points_within(cells, limits, what)
    if len(rows) < GRID_FILL * cells:
        raise PromiseRefused(
            f"{what} holds {len(rows):,} points: less than 1 in {round(1 / GRID_FILL)} of its "
            "pixels measured"
        )
    return shape


# --- text -------------------------------------------------------------------------------


def _text(path: Path, size: int, limits: ReaderLimits) -> None:
    """Rows of at least three numbers take at least six bytes: where that could exceed
    the limit, the rows are counted."""
    if size // 6 <= limits.max_points:
        return
    rows = 0
    with open(path, "rb") as handle:
        while chunk := handle.read(1 << 24):
            rows += chunk.count(b"\n")
    _points_within(rows, limits, "the text file")


_CHECKS = {
    "ply-ascii": _ply,
    "ply-big-endian": _ply,
    "pcd": _pcd,
    "las": _las,
    "laz": _las,
    "e57": _e57,
    "xyz": _text,
    "pts": _text,
}
