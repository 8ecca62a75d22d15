"""Zip and tar archives (plain, gzip, bzip2 or xz) read safely: members listed with their
sizes before anything is read, read under limits, never extracted by their own paths.

A desktop's leftovers (``__MACOSX/``, ``._*``) are not the user's files and are skipped.

What an archive expands to is checked, not trusted: a zip member may not declare more than
``MAX_EXPANSION_RATIO`` times its packed bytes, and is counted again while it is read (in
chunks, stopping at the first byte past its limit); a compressed tar is one stream, metered
as a whole — decompression stops once it passes ``MAX_EXPANSION_RATIO`` times the file's
bytes — so listing or reading a bomb costs at most that many bytes of work. Below
``RATIO_FREE_BYTES`` any ratio is accepted (a small text compresses to almost nothing and
cannot hurt), and nothing expands past ``MAX_EXPANDED_BYTES``.
"""

from __future__ import annotations

import bz2
import gzip
import json
import lzma
import tarfile
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO

import numpy as np

MAX_EXPANSION_RATIO = 200
"""Most a member (zip) or a compressed stream (tar) may expand: real frames, scans and texts
compress 1–10×; 200× is bytes of nothing."""
RATIO_FREE_BYTES = 1 << 20
MAX_EXPANDED_BYTES = 16 << 30
"""Largest sum of the members' sizes: four times the default upload limit
(``VISTA_MAX_UPLOAD_MB`` = 4096), what a job may have to unpack on its disk."""
MAX_MEMBERS = 100_000
"""Files an archive may list (a KITTI drive of a few thousand frames has ~10 000); each
listed member costs memory before anything is read."""
MAX_ZIP_DIRECTORY_BYTES = 64 << 20
"""A zip's central directory is read whole by ``zipfile`` before any check can run."""
MAX_RECORD_BYTES = 64 << 20
"""Largest single read a tar listing may ask for (a long-name or pax header that large is
not a file list)."""
READ_CHUNK_BYTES = 1 << 20
MAX_IMAGE_PIXELS = 64_000_000
"""Largest frame decoded (an 8K frame is 33 Mpx): a PNG or JPEG's header may promise more
pixels than memory holds."""
MAX_JSON_DEPTH = 256
"""Deepest nesting of arrays and objects in a JSON document; Python's parser recurses per
level, and vista's documents nest a few levels."""
JSON_SCAN_CHUNK_BYTES = 4 << 20
COMPRESSION_MAGIC = {
    b"\x1f\x8b": "application/gzip",
    b"BZh": "application/x-bzip2",
    b"\xfd7zXZ\x00": "application/x-xz",
}
DAMAGE = (
    zipfile.BadZipFile,
    tarfile.TarError,
    OSError,
    EOFError,
    zlib.error,
    lzma.LZMAError,
    UnicodeDecodeError,
)
"""What the archive modules raise on a damaged file (gzip's and bz2's errors are OSErrors)."""
UNREADABLE = (NotImplementedError, RuntimeError)
"""A zip's compression method Python lacks (Deflate64), an encrypted zip."""


class ArchiveError(ValueError):
    """The archive cannot be read as asked (the sentence says why)."""


@dataclass(frozen=True)
class Member:
    name: str
    size: int
    info: object
    """The archive's own record (``ZipInfo`` or ``TarInfo``)."""
    expands_to: int = MAX_EXPANDED_BYTES
    """Most bytes reading it may give (a zip member: its packed bytes × the ratio; a tar's
    stream is metered as a whole)."""


def expansion_limit(packed_bytes: int) -> int:
    """Most bytes ``packed_bytes`` of compressed data may expand to."""
    return min(MAX_EXPANDED_BYTES, max(RATIO_FREE_BYTES, MAX_EXPANSION_RATIO * packed_bytes))


def _mib(size: int) -> str:
    return f"{size / 2**20:,.1f} MiB" if size >= 2**20 else f"{size:,} bytes"


def skipped(name: str) -> bool:
    """A desktop's leftovers, not the user's files."""
    return name.startswith("__MACOSX/") or PurePosixPath(name).name.startswith("._")


class _MeteredStream:
    """A decompressed stream that refuses to go past ``limit`` bytes: tarfile skips a member
    by seeking, which decompresses it, so the seek is checked before it is made. The limit is
    on the furthest point reached (going back to re-read a member costs no new budget; vista
    reads an archive in at most three passes)."""

    def __init__(self, stream: IO[bytes], limit: int, packed_bytes: int) -> None:
        self.stream = stream
        self.limit = limit
        self.packed_bytes = packed_bytes
        self.position = 0

    def _refuse(self) -> ArchiveError:
        return ArchiveError(
            f"it expands to more than {_mib(self.limit)}, the most its "
            f"{_mib(self.packed_bytes)} may give ({MAX_EXPANSION_RATIO}× below "
            f"{MAX_EXPANDED_BYTES >> 30} GiB; real files compress far less)"
        )

    def read(self, size: int | None = -1) -> bytes:
        room = self.limit - self.position
        if size is None or size < 0 or size > room:
            size = room + 1  # one byte past the limit tells a bomb from a stream ending there
        if size > MAX_RECORD_BYTES:
            raise ArchiveError(f"a tar record asks for {_mib(size)} at once, not a file list")
        data = self.stream.read(size)
        self.position += len(data)
        if self.position > self.limit:
            raise self._refuse()
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        target = offset + (self.position if whence == 1 else 0)
        if whence not in (0, 1) or target < 0:
            raise OSError("a tar stream seeks only from its start or its position")
        if target > self.limit:
            raise self._refuse()
        self.position = self.stream.seek(target)
        return self.position

    def tell(self) -> int:
        return self.position


def _decompressed(raw: IO[bytes], head: bytes) -> IO[bytes] | None:
    """The stream inside a gzip, bzip2 or xz file; None for anything else."""
    if head.startswith(b"\x1f\x8b"):
        return gzip.GzipFile(fileobj=raw, mode="rb")
    if head.startswith(b"BZh"):
        return bz2.BZ2File(raw)
    if head.startswith(b"\xfd7zXZ\x00"):
        return lzma.LZMAFile(raw)
    return None


def _open_tar(path: Path, raw: IO[bytes]) -> tarfile.TarFile:
    """The tar in ``raw``, read through a meter (a plain tar's only to bound a header's
    single read); tarfile's errors."""
    stream = _decompressed(raw, raw.read(6))
    raw.seek(0)
    size = path.stat().st_size
    metered = _MeteredStream(stream or raw, expansion_limit(size), size)
    return tarfile.open(fileobj=metered, mode="r:")


def _tar_members(archive: tarfile.TarFile) -> list[Member]:
    """The tar's files, listed until there are more than ``MAX_MEMBERS``."""
    members = []
    for info in archive:
        if info.isfile():
            members.append(Member(info.name, info.size, info))
            if len(members) > MAX_MEMBERS:
                raise ArchiveError(f"it holds more than {MAX_MEMBERS:,} files")
    return members


def _check_zip_directory(path: Path) -> None:
    """The zip's end record read first: a directory of millions of entries is refused
    before ``zipfile`` reads it all into memory."""
    with open(path, "rb") as handle:
        # zipfile's own reader of the end record (private, unchanged since Python 2)
        record = zipfile._EndRecData(handle)
    if record is None:
        return
    entries, directory_bytes = record[zipfile._ECD_ENTRIES_TOTAL], record[zipfile._ECD_SIZE]
    if entries > MAX_MEMBERS or directory_bytes > MAX_ZIP_DIRECTORY_BYTES:
        raise ArchiveError(
            f"its directory lists {entries:,} entries in {_mib(directory_bytes)} "
            f"(at most {MAX_MEMBERS:,} files)"
        )


def _zip_members(archive: zipfile.ZipFile) -> list[Member]:
    """The zip's files, each refused when it declares more than its packed bytes may give."""
    members = []
    for info in archive.infolist():
        if info.is_dir():
            continue
        allowed = expansion_limit(info.compress_size)
        if info.file_size > allowed:
            raise ArchiveError(
                f"{info.filename} expands from {_mib(info.compress_size)} to "
                f"{_mib(info.file_size)}, more than the {MAX_EXPANSION_RATIO}× any real file "
                "compresses"
            )
        members.append(Member(info.filename, info.file_size, info, allowed))
    return members


def check_total(members: list[Member], packed_bytes: int) -> None:
    """The members' declared sizes add up to what ``packed_bytes`` may expand to."""
    total = sum(m.size for m in members)
    if total > expansion_limit(packed_bytes):
        raise ArchiveError(
            f"its files add up to {_mib(total)}, more than {_mib(expansion_limit(packed_bytes))} "
            f"(at most {MAX_EXPANSION_RATIO}× the archive, never more than "
            f"{MAX_EXPANDED_BYTES >> 30} GiB)"
        )


@contextmanager
def opened(path: Path, hint: str) -> Iterator[tuple[str, list[Member], object]]:
    """(``zip`` or ``tar``, the files without a desktop's leftovers, the open archive);
    ArchiveError for anything else, ending with ``hint`` (how to pack one), and for an archive
    whose listing says or shows it expands too far."""
    packed_bytes = Path(path).stat().st_size
    if zipfile.is_zipfile(path):
        try:
            _check_zip_directory(path)
            archive = zipfile.ZipFile(path)
        except ArchiveError:
            raise
        except (*DAMAGE, ValueError) as exc:
            raise ArchiveError(f"a damaged zip archive ({exc})") from None
        with archive:
            members = _zip_members(archive)
            check_total(members, packed_bytes)
            yield "zip", [m for m in members if not skipped(m.name)], archive
        return
    with open(path, "rb") as raw:
        try:
            archive = _open_tar(path, raw)
        except ArchiveError:
            raise
        except (*DAMAGE, ValueError):
            raise ArchiveError(f"not a zip or tar archive ({hint})") from None
        with archive:
            try:
                members = _tar_members(archive)
            except ArchiveError:
                raise
            except (*DAMAGE, ValueError) as exc:
                raise ArchiveError(f"a damaged tar archive ({exc})") from None
            check_total(members, packed_bytes)
            yield "tar", [m for m in members if not skipped(m.name)], archive


def _read_chunks(handle: IO[bytes], member: Member, limit: int) -> bytes:
    """``handle`` read in chunks, stopping at the first byte past ``limit``."""
    parts, total = [], 0
    while True:
        chunk = handle.read(min(READ_CHUNK_BYTES, limit + 1 - total))
        if not chunk:
            return b"".join(parts)
        parts.append(chunk)
        total += len(chunk)
        if total > limit:
            raise ArchiveError(
                f"{member.name} expands past {_mib(limit)} when read, more than it may give"
            )


def read_member(form: str, archive: object, member: Member, limit: int) -> bytes:
    """One member's bytes; ArchiveError when it is (or, read, turns out) larger than
    ``limit`` or than its packed bytes may give, or the archive is damaged there."""
    if member.size > limit:
        raise ArchiveError(f"{member.name} is {member.size:,} bytes; at most {limit:,} are read")
    try:
        if form == "zip":
            with archive.open(member.info) as handle:  # type: ignore[attr-defined]
                return _read_chunks(handle, member, min(limit, member.expands_to))
        handle: IO[bytes] | None = archive.extractfile(member.info)  # type: ignore[attr-defined]
        return _read_chunks(handle, member, limit) if handle is not None else b""
    except ArchiveError:
        raise
    except (*DAMAGE, ValueError) as exc:
        raise ArchiveError(f"{member.name} is damaged in the archive ({exc})") from None
    except UNREADABLE as exc:
        raise ArchiveError(f"{member.name} cannot be read ({exc})") from None


def read_in_order(
    form: str, archive: object, members: list[Member], limits: dict[str, int]
) -> Iterator[tuple[Member, bytes]]:
    """The members named in ``limits`` (name → most bytes read) with their bytes, in the
    archive's own order: a compressed tar is one stream, read out of order every member
    would decompress it again from the start."""
    for member in members:
        if member.name in limits:
            yield member, read_member(form, archive, member, limits[member.name])


def media_type(path: Path, form: str) -> str:
    """``application/zip``, a compressed tar's compression or ``application/x-tar``."""
    if form == "zip":
        return "application/zip"
    with open(path, "rb") as handle:
        head = handle.read(6)
    compressed = [kind for magic, kind in COMPRESSION_MAGIC.items() if head.startswith(magic)]
    return compressed[0] if compressed else "application/x-tar"


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG's IHDR or a JPEG's start-of-frame header; None when the
    bytes are neither."""
    if data.startswith(b"\x89PNG\r\n\x1a\n") and data[12:16] == b"IHDR" and len(data) >= 24:
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if not data.startswith(b"\xff\xd8"):
        return None
    offset = 2
    while offset + 9 <= len(data) and data[offset] == 0xFF:
        marker = data[offset + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # markers without a length
            offset += 2
            continue
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # start of frame
            height = int.from_bytes(data[offset + 5 : offset + 7], "big")
            return int.from_bytes(data[offset + 7 : offset + 9], "big"), height
        offset += 2 + int.from_bytes(data[offset + 2 : offset + 4], "big")
    return None


def decode_image(name: str, data: bytes) -> np.ndarray:
    """A member's PNG or JPEG decoded as stored (depth, channels); ArchiveError naming the
    member when it is neither, promises more than ``MAX_IMAGE_PIXELS`` or OpenCV cannot
    decode it."""
    import cv2

    size = image_size(data)
    if size is None:
        raise ArchiveError(f"{name} is neither a PNG nor a JPEG image")
    if size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise ArchiveError(
            f"{name} is {size[0]:,} × {size[1]:,} pixels; at most "
            f"{MAX_IMAGE_PIXELS / 1e6:.0f} million are decoded"
        )
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None or image.size == 0:
        raise ArchiveError(f"{name} is an image OpenCV cannot decode: damaged or truncated")
    return image


def _escaped_quotes(
    chunk: np.ndarray, quote_at: np.ndarray, carried: int
) -> tuple[np.ndarray, int]:
    """Which of the quotes at ``quote_at`` are escaped (after an odd run of backslashes;
    ``carried``: the parity of the run the previous chunk ended with), and the parity of the
    run this chunk ends with."""
    backslash_at = np.flatnonzero(chunk == ord("\\"))
    if len(backslash_at) == 0:
        return (quote_at == 0) & bool(carried), 0
    breaks = np.flatnonzero(np.diff(backslash_at) != 1)
    starts = backslash_at[np.concatenate(([0], breaks + 1))]
    ends = backslash_at[np.concatenate((breaks, [len(backslash_at) - 1]))]
    odd = (ends - starts + 1 + np.where(starts == 0, carried, 0)) % 2 == 1
    escaped = np.isin(quote_at - 1, ends[odd]) | ((quote_at == 0) & bool(carried))
    ends_with_run = ends[-1] == len(chunk) - 1
    return escaped, int(odd[-1]) if ends_with_run else 0


def json_depth(data: np.ndarray, *, stop_above: int = MAX_JSON_DEPTH) -> int:
    """The deepest nesting of arrays and objects in UTF-8 JSON ``data`` ((N,) uint8, a
    memory map will do), found without parsing — nor recursing: a running sum over the
    brackets outside strings, strings told by their unescaped quotes (a quote after an odd
    run of backslashes is escaped). Scanned in chunks, carrying the depth, the string state
    and the backslashes at a chunk's end; stops once the depth passes ``stop_above``.

    In UTF-8 the bytes of ``"[]{}\\`` never occur inside another character, and the parser
    agrees with this count up to its first syntax error, so a document that passes never
    makes the parser recurse deeper."""
    deepest, depth, in_string, backslashes = 0, 0, 0, 0  # backslashes: the carried run's parity
    for start in range(0, len(data), JSON_SCAN_CHUNK_BYTES):
        chunk = np.asarray(data[start : start + JSON_SCAN_CHUNK_BYTES])
        quote_at = np.flatnonzero(chunk == ord('"'))
        escaped, backslashes_after = _escaped_quotes(chunk, quote_at, backslashes)
        quote_at = quote_at[~escaped]
        step = ((chunk == ord("[")) | (chunk == ord("{"))).view(np.int8) - (
            (chunk == ord("]")) | (chunk == ord("}"))
        ).view(np.int8)
        bracket_at = np.flatnonzero(step)
        outside = (np.searchsorted(quote_at, bracket_at) + in_string) % 2 == 0
        running = depth + np.cumsum(step[bracket_at[outside]], dtype=np.int64)
        if len(running):
            deepest = max(deepest, int(running.max()))
            depth = int(running[-1])
        if deepest > stop_above:
            return deepest
        in_string = (len(quote_at) + in_string) % 2
        backslashes = backslashes_after
    return deepest


class JsonTooDeep(ValueError):
    """A JSON document nests deeper than ``MAX_JSON_DEPTH`` (the words follow its name)."""


def parse_json(data: bytes) -> object:
    """UTF-8 JSON parsed once its nesting is known to be at most ``MAX_JSON_DEPTH``;
    JsonTooDeep, or ValueError with the parser's reason."""
    depth = json_depth(np.frombuffer(data, np.uint8))
    if depth > MAX_JSON_DEPTH:
        raise JsonTooDeep(f"nests arrays or objects more than {MAX_JSON_DEPTH} levels deep")
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise ValueError("not UTF-8 text") from None
    except ValueError as exc:  # also Python's limit of 4300 digits on an integer
        raise ValueError(str(exc)) from None


def read_json(path: Path) -> object:
    """A JSON file parsed as ``parse_json`` parses; ValueError naming the file and why."""
    try:
        return parse_json(Path(path).read_bytes())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except ValueError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None


def write_tar_gz(out: Path, files: list[tuple[Path, str]]) -> Path:
    """``files`` (path, name in the archive), in that order, as a tar.gz at ``out``."""
    import tarfile

    with tarfile.open(out, "w:gz") as archive:
        for path, name in files:
            archive.add(path, arcname=name)
    return out
