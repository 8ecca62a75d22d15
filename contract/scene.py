"""What a service puts in 3D: in an inspection's scene, named groups of lines in the robot's
base frame (mm) — a job kind that has results to show there names a ``present`` hook (as it
names its handler), which the supervisor's scene export calls with the newest file of the
output it reads; and a job's own scene (``JobScene``: lines, points, boxes moving frame by
frame, +Z up, mm), which its kind's ``scene`` hook builds from the job's files and the
supervisor writes as glTF. The supervisor draws what they return, knowing nothing of the
files' layout."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

if TYPE_CHECKING:
    from contract.views import JobFiles


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


@dataclass(frozen=True)
class PointSet:
    """Points drawn as they are (a depth map's cloud, a LiDAR scan)."""

    name: str
    points_mm: np.ndarray
    """(N, 3) in the scene's frame: +Z up, mm."""
    colours_rgb: np.ndarray | None = None
    """(N, 3) uint8, or None."""
    shown_at_s: float | None = None
    """None: always shown; else only for the frame starting then (``JobScene.frame_s`` long):
    one scan of a drive."""
    extras: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Surface:
    """Triangles drawn in one colour, translucent where its alpha is below 1 (a part's
    nominal behind the scan's deviation colours)."""

    name: str
    vertices_mm: np.ndarray
    """(V, 3) in the scene's frame: +Z up, mm."""
    faces: np.ndarray
    """(F, 3) vertex indices, counter-clockwise seen from outside."""
    colour_rgba: tuple[float, float, float, float]
    extras: dict = field(default_factory=dict)


@dataclass(frozen=True)
class MovingBox:
    """A box that moves frame by frame (a tracked object): its pose at each key time; or,
    with one key and ``shown_at_s``, a box of one frame (a detection)."""

    name: str
    size_mm: tuple[float, float, float]
    """Length (along its x), width (y), height (z)."""
    times_s: np.ndarray
    """(K,) increasing."""
    centres_mm: np.ndarray
    """(K, 3) the box's centre, +Z up, mm."""
    yaw_rad: np.ndarray
    """(K,) its heading about +Z."""
    colour_rgba: tuple[float, float, float, float]
    extras: dict = field(default_factory=dict)
    shown_at_s: float | None = None
    """As ``PointSet.shown_at_s``: None, always shown; else only for that frame."""


@dataclass(frozen=True)
class JobScene:
    """A job's results in 3D (its kind's ``scene`` hook): the supervisor writes it as glTF
    2.0 (metres, +Y up) under a node ``job-<id>``, moving boxes animated one key a frame."""

    lines: tuple[LineGroup, ...] = ()
    points: tuple[PointSet, ...] = ()
    boxes: tuple[MovingBox, ...] = ()
    surfaces: tuple[Surface, ...] = ()
    frame_s: float = 0.1
    """How long one frame is shown (``PointSet.shown_at_s``)."""
    frame: str = ""
    """What the scene's +Z-up frame is, in words (the first camera's, the LiDAR's, …)."""
    extras: dict = field(default_factory=dict)
    """The run's figures, JSON-able: a headset shows them beside the scene."""


SceneHook = Callable[["JobFiles", int], JobScene]
"""A kind's scene hook: its job's files and a point budget to the scene."""
