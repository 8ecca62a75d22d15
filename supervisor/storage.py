"""Artifact storage: a folder (local, or shared between machines for scale-out).

Files are written to a temporary name inside the storage folder, hashed while they are
written, and renamed into place only once complete, so a reader never sees half a file
and a failed upload leaves nothing behind (a killed process's ``.part`` files are removed
at the next start-up: ``remove_stale_temp_files``).

A file is durable before its database row commits, else a power loss could leave a
committed row pointing at an empty or missing file: whoever writes a temporary file
(``receive``, ``put_file``, ``put_bytes``) syncs it to disk before ``commit`` renames it
into place, and ``commit`` syncs its folder after the rename (and the parent of a folder
it creates). That is one fsync per file and one per folder; an upload's file is synced
before the request's database transaction begins, so no writer waits on that. Folders
and files are private to the server's user (0700, 0600): they hold customers' scans.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import os
import re
import shutil
import time
import uuid
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

URI_SCHEME = "file:"
CHUNK_BYTES = 1024 * 1024
PRIVATE_FILE_MODE = 0o600
PRIVATE_DIR_MODE = 0o700


class UploadTooLarge(Exception):
    def __init__(self, limit_bytes: int) -> None:
        super().__init__(limit_bytes)
        self.limit_bytes = limit_bytes


@dataclass(frozen=True)
class StoredFile:
    uri: str
    size_bytes: int
    sha256: str


@dataclass(frozen=True)
class Removed:
    """What a clean-up removed: how many files or folders, and their size."""

    count: int
    size_bytes: int


def safe_name(name: str) -> str:
    """A file name kept as it was but for characters other than letters, digits, ``._-``,
    spaces and parentheses (``wing (2).ply`` stays)."""
    cleaned = re.sub(r"[^A-Za-z0-9._() -]+", "_", os.path.basename(name))
    cleaned = re.sub(r" {2,}", " ", cleaned).strip("._ ")
    return cleaned[:120] or "artifact"


def tree_size(path: Path) -> int:
    """Bytes of the files under ``path`` (files that vanish meanwhile count nothing)."""
    total = 0
    for folder, _dirs, files in os.walk(path):
        for name in files:
            with contextlib.suppress(FileNotFoundError):
                total += os.lstat(os.path.join(folder, name)).st_size
    return total


def _open_private(path: Path) -> BinaryIO:
    """A new file for writing that only the server's user can read (0600)."""
    return open(path, "xb", opener=lambda p, flags: os.open(p, flags, PRIVATE_FILE_MODE))


def _sync(out: BinaryIO) -> None:
    """Flush ``out`` and sync its data to disk."""
    out.flush()
    os.fsync(out.fileno())


def _fsync_path(path: Path) -> None:
    """Sync ``path`` (a file, or a folder's entries) to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _make_private_dirs(path: Path) -> None:
    """Create ``path`` and its missing parents as private folders (0700), syncing the
    parent of each one made so the new entry survives a power loss too."""
    if path.is_dir():
        return
    _make_private_dirs(path.parent)
    try:
        path.mkdir(mode=PRIVATE_DIR_MODE)
    except FileExistsError:  # another process made it meanwhile (and syncs it)
        return
    _fsync_path(path.parent)


class Storage:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        _make_private_dirs(self.root / "tmp")

    def path(self, uri: str) -> Path:
        if not uri.startswith(URI_SCHEME):
            raise ValueError(f"not a storage uri: {uri}")
        relative = Path(uri[len(URI_SCHEME) :])
        if relative.is_absolute() or ".." in relative.parts:
            raise ValueError(f"storage uri escapes the storage folder: {uri}")
        return self.root / relative

    def new_temp_path(self) -> Path:
        return self.root / "tmp" / f"{uuid.uuid4().hex}.part"

    def _final_uri(self, inspection_id: int, name: str) -> str:
        return f"{URI_SCHEME}inspections/{inspection_id}/{uuid.uuid4().hex[:12]}-{safe_name(name)}"

    async def receive(self, chunks: AsyncIterator[bytes], *, limit_bytes: int) -> StoredFile:
        """Stream ``chunks`` into a temporary file; returns its temp uri, size and sha256."""
        temp = self.new_temp_path()
        digest = hashlib.sha256()
        size = 0
        try:
            with _open_private(temp) as out:
                async for chunk in chunks:
                    size += len(chunk)
                    if size > limit_bytes:
                        raise UploadTooLarge(limit_bytes)
                    digest.update(chunk)
                    out.write(chunk)
                await asyncio.to_thread(_sync, out)  # seconds for gigabytes: off the event loop
        except BaseException:
            temp.unlink(missing_ok=True)
            raise
        return StoredFile(
            uri=f"{URI_SCHEME}tmp/{temp.name}", size_bytes=size, sha256=digest.hexdigest()
        )

    def adopt(self, path: Path) -> StoredFile:
        """A file written into the temporary area by other code (an upload converted to
        vista's format): synced, hashed, and named by its temp uri."""
        if path.parent != self.root / "tmp":
            raise ValueError(f"{path} is not in the storage's temporary area")
        digest = hashlib.sha256()
        with open(path, "rb") as handle:
            while chunk := handle.read(CHUNK_BYTES):
                digest.update(chunk)
            os.fsync(handle.fileno())
        return StoredFile(
            uri=f"{URI_SCHEME}tmp/{path.name}",
            size_bytes=path.stat().st_size,
            sha256=digest.hexdigest(),
        )

    def commit(self, temp_uri: str, *, inspection_id: int, name: str) -> str:
        """Move a temporary file (synced by its writer) to its final place and sync the
        folder that now lists it; returns the final uri."""
        uri = self._final_uri(inspection_id, name)
        target = self.path(uri)
        _make_private_dirs(target.parent)
        os.replace(self.path(temp_uri), target)
        _fsync_path(target.parent)
        return uri

    def put_file(self, source: Path, *, inspection_id: int, name: str) -> StoredFile:
        """Copy a finished local file into storage (job outputs)."""
        digest = hashlib.sha256()
        temp = self.new_temp_path()
        size = 0
        try:
            with open(source, "rb") as src, _open_private(temp) as out:
                while chunk := src.read(CHUNK_BYTES):
                    digest.update(chunk)
                    out.write(chunk)
                    size += len(chunk)
                _sync(out)
        except BaseException:
            temp.unlink(missing_ok=True)
            raise
        uri = self.commit(f"{URI_SCHEME}tmp/{temp.name}", inspection_id=inspection_id, name=name)
        return StoredFile(uri=uri, size_bytes=size, sha256=digest.hexdigest())

    def put_bytes(self, data: bytes, *, inspection_id: int, name: str) -> StoredFile:
        temp = self.new_temp_path()
        try:
            with _open_private(temp) as out:
                out.write(data)
                _sync(out)
        except BaseException:
            temp.unlink(missing_ok=True)
            raise
        uri = self.commit(f"{URI_SCHEME}tmp/{temp.name}", inspection_id=inspection_id, name=name)
        return StoredFile(uri=uri, size_bytes=len(data), sha256=hashlib.sha256(data).hexdigest())

    def remove_stale_temp_files(self, *, older_than_s: float) -> Removed:
        """Remove the ``.part`` files not written for ``older_than_s`` seconds: left by a
        process killed during an upload or a job output, they are never renamed."""
        cutoff = time.time() - older_than_s
        count = size_bytes = 0
        for path in (self.root / "tmp").glob("*.part"):
            try:
                stat = path.stat()
                if stat.st_mtime >= cutoff:
                    continue
                path.unlink()
            except FileNotFoundError:  # renamed or removed by its owner meanwhile
                continue
            count, size_bytes = count + 1, size_bytes + stat.st_size
        return Removed(count, size_bytes)

    def delete(self, uri: str) -> None:
        self.path(uri).unlink(missing_ok=True)

    def export_dir(self, inspection_id: int) -> Path:
        """Where an inspection's built exports (scene.glb) are cached."""
        return self.root / "exports" / str(inspection_id)

    def delete_inspection(self, inspection_id: int) -> None:
        shutil.rmtree(self.root / "inspections" / str(inspection_id), ignore_errors=True)
        shutil.rmtree(self.export_dir(inspection_id), ignore_errors=True)
