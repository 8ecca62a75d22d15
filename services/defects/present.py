"""The measurement in the inspection's 3D scene (``contract.scene``): each measured panel's
outline and each seam's line, read from the measure job's result (light: the API calls it)."""

from __future__ import annotations

import json
from pathlib import Path

from contract.scene import LineGroup, Polyline

OUTLINE_RGBA = (0.35, 0.85, 1.0, 1.0)
SEAM_RGBA = (1.0, 1.0, 1.0, 1.0)
UNMEASURED_RGBA = (1.0, 0.42, 0.0, 1.0)
"""A seam that yields no gap: orange, and its reason in the extras."""


def scene_lines(result_path: Path) -> tuple[LineGroup, ...]:
    """``outlines``: a closed ``panel-<id>`` line around each panel's top (extras: panel
    id, centroid, normal, area — the ids seams and steps refer to); ``seams``: a
    ``seam-<id>`` line through its sections from start to end (extras: seam id, panels,
    length, start and end, mm, and how many of its sections are unmeasured);
    ``unmeasured-seams``: the same for each seam that yields no gap, with why
    (``unmeasured``)."""
    result = json.loads(result_path.read_text())
    outlines = tuple(
        Polyline(
            f"panel-{p['id']}",
            p["outline"],
            "loop",
            {
                "panel": p["id"],
                "centroid_mm": p["centroid"],
                "normal": p["normal"],
                "area_mm2": p["area_mm2"],
            },
        )
        for p in result.get("panels", [])
        if len(p["outline"]) >= 3
    )
    seams = [
        Polyline(
            f"seam-{s['id']}",
            [s["start"], *(section["at"] for section in s.get("sections", [])), s["end"]],
            "strip",
            {
                "seam": s["id"],
                "panels": s["panels"],
                "length_mm": s["length_mm"],
                "start_mm": s["start"],
                "end_mm": s["end"],
                "sections_unmeasured": s.get("sections_unmeasured", 0),
                "sections": s.get("sections_unmeasured", 0) + s.get("sections_measured", 0),
                **({"unmeasured": s["unmeasured"]} if s.get("unmeasured") else {}),
            },
        )
        for s in result.get("seams", [])
    ]
    return (
        LineGroup("outlines", "panel-outline", OUTLINE_RGBA, outlines),
        LineGroup(
            "seams", "seam", SEAM_RGBA, tuple(s for s in seams if "unmeasured" not in s.extras)
        ),
        LineGroup(
            "unmeasured-seams",
            "seam-unmeasured",
            UNMEASURED_RGBA,
            tuple(s for s in seams if "unmeasured" in s.extras),
        ),
    )


def no_lines(result_path: Path) -> tuple[LineGroup, ...]:
    """A comparison draws no lines in the inspection's scene: its scan (coloured by its
    deviation), its nominal and its findings' rings are the scene."""
    return ()
