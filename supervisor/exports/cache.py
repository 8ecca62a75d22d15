"""Scene files cached on disk, safe with any number of readers and builders at once.

A cached file is written under a unique temporary name and renamed into place, and every
reader takes an open handle before it answers: a file a builder later replaces or
deletes (one budget kept per job, one version per run shown) is still read whole through
that handle. Two readers of one scene at different point budgets got 500s when each
build deleted the file the other was about to send (issue 55).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from starlette.responses import StreamingResponse

CHUNK_BYTES = 1024 * 1024
"""A scene is megabytes: each 64 KiB default read would be a trip through a thread."""


def open_cached(path: Path) -> BinaryIO | None:
    """The cached file open for reading, or None if it is not (or no longer) there."""
    try:
        return open(path, "rb")
    except FileNotFoundError:
        return None


def publish(path: Path, data: bytes) -> BinaryIO:
    """``data`` written to a unique temporary file beside ``path`` and renamed to it;
    returned open for reading from its start (whatever happens to ``path`` next)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    handle = os.fdopen(fd, "w+b")
    try:
        handle.write(data)
        handle.flush()
        os.replace(temp, path)
    except BaseException:
        handle.close()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp)
        raise
    handle.seek(0)
    return handle


def remove_others(folder: Path, pattern: str, keep: Path) -> None:
    """Delete the files matching ``pattern`` but ``keep`` (readers holding one open read
    on: a deleted file lives until its last handle closes)."""
    for other in folder.glob(pattern):
        if other != keep:
            other.unlink(missing_ok=True)


class OpenFileResponse(StreamingResponse):
    """An open file sent whole in ``CHUNK_BYTES`` reads, with its length, and closed."""

    def __init__(self, handle: BinaryIO, *, media_type: str, headers: dict[str, str]) -> None:
        size = os.fstat(handle.fileno()).st_size
        super().__init__(
            _chunks(handle),
            media_type=media_type,
            headers={**headers, "Content-Length": str(size)},
        )


def _chunks(handle: BinaryIO) -> Iterator[bytes]:
    with handle:
        while chunk := handle.read(CHUNK_BYTES):
            yield chunk
