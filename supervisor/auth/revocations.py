"""Telling every API process that tokens were revoked, so the next request sees it.

Each API process caches the tokens it has checked (see ``deps.TokenCache``). A revocation,
a deactivation or a password change — through the API or the ``vista user`` commands —
rewrites a small stamp file in the artifact folder once its transaction committed; a
cached token checked before the stamp's last change is checked again. The artifact folder
is the one place every API process and machine of one vista shares, and a ``stat`` costs
microseconds. A change made by hand in the database reaches the caches within their
lifetime (``TokenCache.ttl_s``).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

STAMP_NAME = ".token-revocations"


class Revocations:
    def __init__(self, folder: Path) -> None:
        self.path = Path(folder) / STAMP_NAME

    def stamp(self) -> int:
        """The stamp now (0 before any revocation)."""
        try:
            return os.stat(self.path).st_mtime_ns
        except FileNotFoundError:
            return 0

    def bump(self) -> None:
        """Mark that tokens changed (call after the change committed)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        now_ns = time.time_ns()
        before = self.stamp()
        # Two bumps within the file system's time resolution must still differ.
        stamp_ns = max(now_ns, before + 1_000)
        self.path.write_text(str(stamp_ns))
        os.utime(self.path, ns=(stamp_ns, stamp_ns))
