"""The floor camera: a pinhole looking straight down at a planar floor (thesis 6.3.2).

The thesis's camera has f = 3.7 mm at h = 110 mm above the floor with a diagonal field of
189.7 mm on the floor, at 60 fps. ``camera.json`` carries what a method needs to turn
pixels into millimetres: the frame size, the frame rate and ``mm_per_px`` on the floor at
the nominal height.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

THESIS_HEIGHT_MM = 110.0
THESIS_FOCAL_MM = 3.7
THESIS_DIAGONAL_MM = 189.7
"""The diagonal field of view on the floor at the thesis's height."""


@dataclass(frozen=True)
class FloorCamera:
    """A camera looking straight down at a planar floor, known by the floor's millimetres
    per pixel at its height (the depth service's perspective camera is ``PinholeCamera``)."""

    width: int
    height: int
    fps: float
    mm_per_px: float
    """Floor distance between neighbouring pixels at ``height_mm``."""
    height_mm: float = THESIS_HEIGHT_MM
    focal_mm: float = THESIS_FOCAL_MM

    @classmethod
    def thesis(cls, width: int = 640, height: int = 480, fps: float = 60.0) -> FloorCamera:
        """The thesis's camera at ``width`` × ``height`` pixels."""
        return cls(width, height, fps, THESIS_DIAGONAL_MM / math.hypot(width, height))

    @property
    def footprint_mm(self) -> tuple[float, float]:
        """The floor the frame covers (width, height) at the nominal height."""
        return self.width * self.mm_per_px, self.height * self.mm_per_px

    def document(self) -> dict:
        return asdict(self)

    @classmethod
    def from_document(cls, doc: object) -> FloorCamera:
        """camera.json read back; ValueError naming the field that is missing or wrong."""
        if not isinstance(doc, dict):
            raise ValueError("camera.json: not a JSON object")
        values = {}
        for name, kind, low, high in (
            ("width", int, 8, 20_000),
            ("height", int, 8, 20_000),
            ("fps", float, 0.1, 10_000.0),
            ("mm_per_px", float, 1e-4, 100.0),
            ("height_mm", float, 1.0, 10_000.0),
            ("focal_mm", float, 0.1, 1_000.0),
        ):
            value = doc.get(name)
            if value is None:
                raise ValueError(f"camera.json: no {name!r}")
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"camera.json: {name} must be a number, not {value!r}")
            if kind is int and value != int(value):
                raise ValueError(f"camera.json: {name} must be a whole number, not {value}")
            if not low <= value <= high:
                raise ValueError(f"camera.json: {name} = {value} is outside {low}–{high}")
            values[name] = kind(value)
        return cls(**values)
