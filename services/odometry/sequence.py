"""A frame sequence in one file: a zip or tar archive (gzip, bzip2 or xz compressed or not) of
what ``vista odometry simulate`` writes — the PNG frames, ``camera.json`` and, when the
truth is known, ``truth.tum``.

The frames may sit in any one folder of the archive (``frames/``, ``seq/frames/`` or the
top); they are taken in name order, numbers by value (``2.png`` before ``10.png``); a
desktop's leftovers (``__MACOSX/``, ``._*``) are skipped. Nothing is extracted by the
archive's own paths: the members are read and written under names of vista's choosing, so a
member called ``../../etc/passwd`` cannot land outside the folder. Sizes are checked before
anything is read: a tar's listing stops once its files pass ``MAX_ARCHIVE_BYTES``, and
camera.json, truth.tum and each frame have limits of their own.
"""

from __future__ import annotations

import json
import lzma
import re
import tarfile
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath
from typing import IO

from services.odometry.camera import Camera
from services.odometry.tum import parse_tum

MAX_ARCHIVE_BYTES = 64 << 30
"""Largest sum of the members' sizes (a zip bomb says its sizes, and is refused by them)."""
MAX_MEMBER_BYTES = {"camera.json": 1 << 20, "truth.tum": 256 << 20, "frame": 256 << 20}
COMPRESSION_MAGIC = {
    b"\x1f\x8b": "application/gzip",
    b"BZh": "application/x-bzip2",
    b"\xfd7zXZ\x00": "application/x-xz",
}
DAMAGE = (zipfile.BadZipFile, tarfile.TarError, OSError, EOFError, zlib.error, lzma.LZMAError)
"""What the archive modules raise on a damaged file (gzip's and bz2's errors are OSErrors)."""
UNREADABLE = (NotImplementedError, RuntimeError)
"""A zip's compression method Python lacks (Deflate64), an encrypted zip."""


class SequenceError(ValueError):
    """The archive is not a frame sequence vista can read (the sentence says why)."""


@dataclass(frozen=True)
class Member:
    name: str
    size: int
    info: object
    """The archive's own record (``ZipInfo`` or ``TarInfo``)."""


@dataclass(frozen=True)
class SequenceArchive:
    """What a sequence archive holds, checked without extracting it."""

    form: str
    """``zip`` or ``tar``."""
    frames: tuple[str, ...]
    """The frames' member names in order."""
    camera: Camera
    camera_member: str
    truth_member: str | None
    """``None``: the archive has no truth."""
    media_type: str = "application/x-tar"
    """``application/zip``, a compressed tar's compression or ``application/x-tar``."""


def _skipped(name: str) -> bool:
    """A desktop's leftovers, not the user's files."""
    return name.startswith("__MACOSX/") or PurePosixPath(name).name.startswith("._")


def _tar_members(archive: tarfile.TarFile) -> list[Member]:
    """The tar's files, listed until their sizes pass ``MAX_ARCHIVE_BYTES``."""
    members, total = [], 0
    for info in archive:
        if info.isfile():
            members.append(Member(info.name, info.size, info))
            total += info.size
            if total > MAX_ARCHIVE_BYTES:
                break
    return members


@contextmanager
def _opened(path: Path) -> Iterator[tuple[str, list[Member], object]]:
    if zipfile.is_zipfile(path):
        try:
            archive = zipfile.ZipFile(path)
        except DAMAGE as exc:
            raise SequenceError(f"a damaged zip archive ({exc})") from None
        with archive:
            members = [
                Member(i.filename, i.file_size, i) for i in archive.infolist() if not i.is_dir()
            ]
            yield "zip", [m for m in members if not _skipped(m.name)], archive
        return
    try:
        archive = tarfile.open(path, "r:*")  # noqa: SIM115 - closed by the with below
    except DAMAGE:
        raise SequenceError(
            "not a zip or tar archive (pack a sequence folder with "
            "`tar czf seq.tar.gz -C SEQ frames camera.json truth.tum`)"
        ) from None
    with archive:
        try:
            members = _tar_members(archive)
        except DAMAGE as exc:
            raise SequenceError(f"a damaged tar archive ({exc})") from None
        yield "tar", [m for m in members if not _skipped(m.name)], archive


def _read(form: str, archive: object, member: Member, limit: int) -> bytes:
    """One member's bytes; SequenceError when it is larger than ``limit`` or the archive
    is damaged there."""
    if member.size > limit:
        raise SequenceError(f"{member.name} is {member.size:,} bytes; at most {limit:,} are read")
    try:
        if form == "zip":
            return archive.read(member.info)
        handle: IO[bytes] | None = archive.extractfile(member.info)
        return handle.read() if handle is not None else b""
    except DAMAGE as exc:
        raise SequenceError(f"{member.name} is damaged in the archive ({exc})") from None
    except UNREADABLE as exc:
        raise SequenceError(f"{member.name} cannot be read ({exc})") from None


def _frame_order(name: str) -> list:
    """Numbers by value: 2.png before 10.png."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def _one(members: list[Member], file_name: str, *, required: bool) -> Member | None:
    found = [m for m in members if PurePosixPath(m.name).name == file_name]
    if len(found) > 1:
        names = ", ".join(m.name for m in found[:3])
        raise SequenceError(f"{len(found)} files called {file_name} ({names}): one")
    if not found and required:
        raise SequenceError(f"no {file_name} in the archive (the camera's size, fps and mm/px)")
    return found[0] if found else None


def _inspect(form: str, members: list[Member], archive: object) -> SequenceArchive:
    if sum(m.size for m in members) > MAX_ARCHIVE_BYTES:
        raise SequenceError(f"its files add up to more than {MAX_ARCHIVE_BYTES >> 30} GiB")
    pngs = sorted({m.name for m in members if m.name.lower().endswith(".png")}, key=_frame_order)
    folders = sorted({str(PurePosixPath(name).parent) for name in pngs})
    if len(folders) > 1:
        shown = ", ".join(folders[:3])
        raise SequenceError(f"the PNG frames must be in one folder, not {len(folders)} ({shown})")
    if len(pngs) < 2:
        raise SequenceError(f"needs at least 2 PNG frames, found {len(pngs)}")
    camera_member = _one(members, "camera.json", required=True)
    try:
        text = _read(form, archive, camera_member, MAX_MEMBER_BYTES["camera.json"])
        camera = Camera.from_document(json.loads(text))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{camera_member.name} is not JSON ({exc})") from None
    except ValueError as exc:
        detail = str(exc).removeprefix("camera.json: ")
        raise SequenceError(f"{camera_member.name}: {detail}") from None
    truth_member = _one(members, "truth.tum", required=False)
    if truth_member is not None:
        try:
            text = _read(form, archive, truth_member, MAX_MEMBER_BYTES["truth.tum"])
            truth = parse_tum(text.decode(), truth_member.name)
        except (UnicodeDecodeError, ValueError) as exc:
            raise SequenceError(f"{truth_member.name}: not a TUM trajectory ({exc})") from None
        if len(truth) != len(pngs):
            raise SequenceError(
                f"{truth_member.name} has {len(truth)} poses for {len(pngs)} frames"
            )
    return SequenceArchive(
        form, tuple(pngs), camera, camera_member.name, truth_member.name if truth_member else None
    )


def inspect_sequence(path: Path) -> SequenceArchive:
    """The archive's frames, camera and truth, checked; SequenceError naming the problem."""
    with _opened(path) as (form, members, archive):
        found = _inspect(form, members, archive)
    if form == "zip":
        return replace(found, media_type="application/zip")
    with open(path, "rb") as handle:
        head = handle.read(6)
    compressed = [kind for magic, kind in COMPRESSION_MAGIC.items() if head.startswith(magic)]
    return replace(found, media_type=compressed[0] if compressed else "application/x-tar")


def extract_sequence(path: Path, out_dir: Path) -> SequenceArchive:
    """The archive written as a sequence folder: ``out_dir/frames/NNNNNN.png`` (in the
    frames' name order), ``camera.json`` and ``truth.tum`` when the archive has one.

    The members are read in the archive's own order (a compressed tar is one stream: read
    out of order, every frame would decompress it again from the start)."""
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    with _opened(path) as (form, members, archive):
        found = _inspect(form, members, archive)
        targets = {name: frames_dir / f"{k:06d}.png" for k, name in enumerate(found.frames)}
        targets[found.camera_member] = out_dir / "camera.json"
        if found.truth_member is not None:
            targets[found.truth_member] = out_dir / "truth.tum"
        for member in members:
            if member.name in targets:
                limit = MAX_MEMBER_BYTES.get(targets[member.name].name, MAX_MEMBER_BYTES["frame"])
                targets[member.name].write_bytes(_read(form, archive, member, limit))
    return found
