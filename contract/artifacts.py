"""An artifact kind as data: its name, what it is, and the hook that checks a file of it.

A service lists the kinds of file it reads and writes in ``ARTIFACT_KINDS`` in its ``kinds``
module, beside its job kinds; the supervisor's registry collects them. The ``inspect`` hook
is named by import path (as ``JobKind.handler`` is) and imported only when a file of the
kind arrives: it reads the file, returns the media type to keep and what it learned, or
refuses with a sentence. Adding a kind of file touches the one service that knows it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from contract.kinds import load_hook


@dataclass(frozen=True)
class Inspected:
    """What a file turned out to be: the media type to keep it under (the content's, not
    the one declared) and what was learned from it, kept as the artifact's metadata."""

    media_type: str
    meta: dict = field(default_factory=dict)
    replacement: Path | None = None
    """A file the hook wrote in place of the upload (a scanner's format converted to
    vista's), in the upload's folder: kept instead of it, named with ``media_type``'s
    extension."""


class ArtifactRefused(ValueError):
    """The file is not what its kind needs. ``reason`` completes "scan_000.ply (kind=scan) …"
    ("is not valid JSON: …"); ``too_large``: refused for its size alone (HTTP 413)."""

    def __init__(self, reason: str, *, too_large: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.too_large = too_large


Inspect = Callable[..., Inspected]
"""A kind's check: ``inspect(path, media_type)`` — the uploaded file and the media type its
sender declared; a hook of point clouds also takes ``units=`` (the unit the sender named)."""


@dataclass(frozen=True)
class ArtifactKind:
    name: str
    description: str
    """What it is, for people (units and frames included): shown by the API."""
    inspect: str | None = None
    """``module:function`` (an ``Inspect``); ``None``: any file, kept as declared."""

    def load_inspect(self) -> Inspect | None:
        return None if self.inspect is None else load_hook(self.inspect)
