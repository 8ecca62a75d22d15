"""Zip and tar archives (plain, gzip, bzip2 or xz) read safely: members listed with their
sizes before anything is read, read under limits, never extracted by their own paths.

A desktop's leftovers (``__MACOSX/``, ``._*``) are not the user's files and are skipped. A
tar's listing stops once its files pass ``MAX_ARCHIVE_BYTES`` (a zip says its sizes).
"""

from __future__ import annotations

import lzma
import tarfile
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO

MAX_ARCHIVE_BYTES = 64 << 30
"""Largest sum of the members' sizes (a zip bomb says its sizes, and is refused by them)."""
COMPRESSION_MAGIC = {
    b"\x1f\x8b": "application/gzip",
    b"BZh": "application/x-bzip2",
    b"\xfd7zXZ\x00": "application/x-xz",
}
DAMAGE = (zipfile.BadZipFile, tarfile.TarError, OSError, EOFError, zlib.error, lzma.LZMAError)
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


def skipped(name: str) -> bool:
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
def opened(path: Path, hint: str) -> Iterator[tuple[str, list[Member], object]]:
    """(``zip`` or ``tar``, the files without a desktop's leftovers, the open archive);
    ArchiveError for anything else, ending with ``hint`` (how to pack one)."""
    if zipfile.is_zipfile(path):
        try:
            archive = zipfile.ZipFile(path)
        except DAMAGE as exc:
            raise ArchiveError(f"a damaged zip archive ({exc})") from None
        with archive:
            members = [
                Member(i.filename, i.file_size, i) for i in archive.infolist() if not i.is_dir()
            ]
            yield "zip", [m for m in members if not skipped(m.name)], archive
        return
    try:
        archive = tarfile.open(path, "r:*")  # noqa: SIM115 - closed by the with below
    except DAMAGE:
        raise ArchiveError(f"not a zip or tar archive ({hint})") from None
    with archive:
        try:
            members = _tar_members(archive)
        except DAMAGE as exc:
            raise ArchiveError(f"a damaged tar archive ({exc})") from None
        yield "tar", [m for m in members if not skipped(m.name)], archive


def read_member(form: str, archive: object, member: Member, limit: int) -> bytes:
    """One member's bytes; ArchiveError when it is larger than ``limit`` or the archive is
    damaged there."""
    if member.size > limit:
        raise ArchiveError(f"{member.name} is {member.size:,} bytes; at most {limit:,} are read")
    try:
        if form == "zip":
            return archive.read(member.info)
        handle: IO[bytes] | None = archive.extractfile(member.info)
        return handle.read() if handle is not None else b""
    except DAMAGE as exc:
        raise ArchiveError(f"{member.name} is damaged in the archive ({exc})") from None
    except UNREADABLE as exc:
        raise ArchiveError(f"{member.name} cannot be read ({exc})") from None


def media_type(path: Path, form: str) -> str:
    """``application/zip``, a compressed tar's compression or ``application/x-tar``."""
    if form == "zip":
        return "application/zip"
    with open(path, "rb") as handle:
        head = handle.read(6)
    compressed = [kind for magic, kind in COMPRESSION_MAGIC.items() if head.startswith(magic)]
    return compressed[0] if compressed else "application/x-tar"


def check_total(members: list[Member]) -> None:
    if sum(m.size for m in members) > MAX_ARCHIVE_BYTES:
        raise ArchiveError(f"its files add up to more than {MAX_ARCHIVE_BYTES >> 30} GiB")
