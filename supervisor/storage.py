"""Artifact storage: a folder (local, or shared between machines for scale-out).

Files are written to a temporary name inside the storage folder, hashed while they are
written, and renamed into place only once complete, so a reader never sees half a file
and a failed upload leaves nothing behind.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import uuid
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

URI_SCHEME = "file:"
CHUNK_BYTES = 1024 * 1024


class UploadTooLarge(Exception):
    def __init__(self, limit_bytes: int) -> None:
        super().__init__(limit_bytes)
        self.limit_bytes = limit_bytes


@dataclass(frozen=True)
class StoredFile:
    uri: str
    size_bytes: int
    sha256: str


def safe_name(name: str) -> str:
    cleaned = re.sub(r"[^A-Za-z0-9._-]+", "_", os.path.basename(name)).strip("._")
    return cleaned[:120] or "artifact"


class Storage:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        (self.root / "tmp").mkdir(parents=True, exist_ok=True)

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
            with open(temp, "wb") as out:
                async for chunk in chunks:
                    size += len(chunk)
                    if size > limit_bytes:
                        raise UploadTooLarge(limit_bytes)
                    digest.update(chunk)
                    out.write(chunk)
        except BaseException:
            temp.unlink(missing_ok=True)
            raise
        return StoredFile(
            uri=f"{URI_SCHEME}tmp/{temp.name}", size_bytes=size, sha256=digest.hexdigest()
        )

    def commit(self, temp_uri: str, *, inspection_id: int, name: str) -> str:
        """Move a received temporary file to its final place; returns the final uri."""
        uri = self._final_uri(inspection_id, name)
        target = self.path(uri)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(self.path(temp_uri), target)
        return uri

    def put_file(self, source: Path, *, inspection_id: int, name: str) -> StoredFile:
        """Copy a finished local file into storage (job outputs)."""
        digest = hashlib.sha256()
        temp = self.new_temp_path()
        size = 0
        try:
            with open(source, "rb") as src, open(temp, "wb") as out:
                while chunk := src.read(CHUNK_BYTES):
                    digest.update(chunk)
                    out.write(chunk)
                    size += len(chunk)
        except BaseException:
            temp.unlink(missing_ok=True)
            raise
        uri = self.commit(f"{URI_SCHEME}tmp/{temp.name}", inspection_id=inspection_id, name=name)
        return StoredFile(uri=uri, size_bytes=size, sha256=digest.hexdigest())

    def put_bytes(self, data: bytes, *, inspection_id: int, name: str) -> StoredFile:
        temp = self.new_temp_path()
        temp.write_bytes(data)
        uri = self.commit(f"{URI_SCHEME}tmp/{temp.name}", inspection_id=inspection_id, name=name)
        return StoredFile(uri=uri, size_bytes=len(data), sha256=hashlib.sha256(data).hexdigest())

    def delete(self, uri: str) -> None:
        self.path(uri).unlink(missing_ok=True)

    def export_dir(self, inspection_id: int) -> Path:
        """Where an inspection's built exports (scene.glb) are cached."""
        return self.root / "exports" / str(inspection_id)

    def delete_inspection(self, inspection_id: int) -> None:
        shutil.rmtree(self.root / "inspections" / str(inspection_id), ignore_errors=True)
        shutil.rmtree(self.export_dir(inspection_id), ignore_errors=True)
