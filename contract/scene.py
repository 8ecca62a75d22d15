"""What a service puts in an inspection's 3D scene: named groups of lines in the robot's
base frame (mm). A job kind that has results to show names a ``present`` hook (as it names
its handler); the supervisor's scene export calls it with the newest file of the output it
reads and draws what it returns, knowing nothing of the file's layout."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal


@dataclass(frozen=True)
class Polyline:
    name: str
    """The node's name, stable across exports: clients find things by it ("seam-3")."""
    points_mm: list[list[float]]
    """Base frame, mm, in order."""
    shape: Literal["loop", "strip"]
    """``loop``: closed (an outline); ``strip``: open (a seam from start to end)."""
    extras: dict
    """What a client shows on picking it (ids, lengths in mm …), JSON-able."""


@dataclass(frozen=True)
class LineGroup:
    name: str
    """The group node's name ("seams")."""
    material: str
    colour_rgba: tuple[float, float, float, float]
    lines: tuple[Polyline, ...]


Present = Callable[[Path], tuple[LineGroup, ...]]
"""A kind's presenter: the newest file of the output it reads, to what the scene draws."""
