"""A service's sample run: files it makes and the steps that run its jobs on them, so that
the supervisor's benches and demos can exercise every service's results (run pages, scenes)
without knowing any of them. A service names its maker in ``kinds.SAMPLE_RUN`` (``module:
function``, a ``SampleMaker``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Upload:
    path: Path
    kind: str
    """Its artifact kind."""
    media_type: str


@dataclass(frozen=True)
class SampleStep:
    name: str
    kind: str
    inputs: tuple[str, ...]
    """Upload labels (keys of ``SampleRun.uploads``)."""
    params: dict = field(default_factory=dict)
    after: tuple[str, ...] = ()


@dataclass(frozen=True)
class SampleRun:
    uploads: dict[str, Upload]
    steps: tuple[SampleStep, ...]
    about: str
    """What the sample is, in words (the bench prints it)."""


SampleMaker = Callable[[Path, int, Path | None], SampleRun]
"""A service's sample run: a work folder, a frame count (how long a drive or sequence is)
and a folder of real data the user points to (None: none; a service uses what it finds
there in its own formats) to the files and steps."""
