"""The simulated assembly's ground truth in the base frame (mm): its panels, seams,
junctions and surface defects, as frozen dataclasses; ``Truth.document()`` is the
``truth.json`` that ``vista defects simulate`` writes and ``Truth.from_document`` reads
it back."""

from __future__ import annotations

from dataclasses import MISSING, asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from services.defects.simulate import Assembly, SeamTruth, layout_normal, layout_to_part
from services.lib.archive import read_json
from services.lib.pointcloud.transforms import apply

Point = tuple[float, float, float]


@dataclass(frozen=True)
class TrueEdge:
    kind: str
    """round, chamfer or square."""
    size_mm: float
    angle_deg: float | None
    """A chamfer's angle; None for the other kinds."""
    burr_mm: float


@dataclass(frozen=True)
class TruePanel:
    id: int
    corners: tuple[Point, ...]
    height_mm: float
    edge: TrueEdge
    area_mm2: float


@dataclass(frozen=True)
class TrueSeam:
    id: int
    panels: tuple[int, int]
    start: Point
    end: Point
    gap_start_mm: float
    gap_end_mm: float
    parallelism_mm: float
    step_mm: float


@dataclass(frozen=True)
class TrueJunction:
    at: Point
    seams: tuple[int, ...]
    gaps_mm: tuple[float, ...]
    """Each seam's gap where it meets the junction."""
    mismatch_mm: float


@dataclass(frozen=True)
class TrueDefect:
    type: str
    """dent, bump, scratch or color."""
    panel: int
    location: Point
    normal: Point
    depth_mm: float | None = None
    """Dents, bumps (how far from the surface) and scratches."""
    diameter_mm: float | None = None
    """Dents, bumps and colour patches (a patch's longest axis)."""
    start: Point | None = None
    """A scratch's ends, its width and length."""
    end: Point | None = None
    width_mm: float | None = None
    length_mm: float | None = None
    delta_e: float | None = None
    """A colour patch's ΔE and area."""
    area_mm2: float | None = None

    @property
    def size_mm(self) -> float:
        """Its diameter, or a scratch's length."""
        return self.diameter_mm or self.length_mm or 0.0

    @property
    def in_recall_target(self) -> bool:
        """Inside the issue's recall target: dents and bumps ≥ 0.2 mm deep, scratches
        ≥ 0.1 mm deep, colour patches ΔE ≥ 5."""
        if self.type in ("dent", "bump"):
            return (self.depth_mm or 0.0) >= 0.2
        if self.type == "scratch":
            return (self.depth_mm or 0.0) >= 0.1
        return (self.delta_e or 0.0) >= 5.0


@dataclass(frozen=True)
class Truth:
    radius_mm: float | None
    """The part's curvature radius (None: flat)."""
    panels: tuple[TruePanel, ...]
    seams: tuple[TrueSeam, ...]
    junctions: tuple[TrueJunction, ...]
    defects: tuple[TrueDefect, ...]

    def document(self) -> dict:
        """The JSON document (a defect carries only the fields of its type)."""
        doc = asdict(self)
        doc["defects"] = [{k: v for k, v in d.items() if v is not None} for d in doc["defects"]]
        return doc

    @classmethod
    def from_document(cls, doc: dict) -> Truth:
        """Read a truth document back; ValueError naming what is missing."""
        try:
            return cls(
                radius_mm=doc.get("radius_mm"),
                panels=tuple(
                    _make(
                        TruePanel,
                        {**p, "edge": _make(TrueEdge, p["edge"], f"panels[{k}].edge")},
                        f"panels[{k}]",
                    )
                    for k, p in enumerate(doc["panels"])
                ),
                seams=tuple(_make(TrueSeam, s, f"seams[{k}]") for k, s in enumerate(doc["seams"])),
                junctions=tuple(
                    _make(TrueJunction, j, f"junctions[{k}]")
                    for k, j in enumerate(doc["junctions"])
                ),
                defects=tuple(
                    _make(TrueDefect, d, f"defects[{k}]") for k, d in enumerate(doc["defects"])
                ),
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a truth document of `vista defects simulate`: no {exc}") from exc

    @classmethod
    def read(cls, path: Path) -> Truth:
        """A truth.json read back; ValueError naming the file and what is wrong."""
        document = read_json(path)
        try:
            return cls.from_document(document)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc


def _make(kind: type, values: dict, where: str) -> Any:
    """``kind`` from a JSON object, lists as tuples, other keys ignored."""
    known = {f.name: f for f in fields(kind)}
    missing = [
        name
        for name, f in known.items()
        if name not in values and f.default is MISSING and f.default_factory is MISSING
    ]
    if missing:
        raise KeyError(f"{where}.{missing[0]}")
    return kind(**{k: _frozen(v) for k, v in values.items() if k in known})


def _frozen(value: Any) -> Any:
    if isinstance(value, list):
        return tuple(_frozen(v) for v in value)
    return value


def seam_gap_mm(assembly: Assembly, seam: SeamTruth, fraction: np.ndarray) -> np.ndarray:
    """True gap at ``fraction`` (0 = start, 1 = end) along the seam, measured in the
    surface at the panels' mean height (a gap across a curved sidewall is an arc)."""
    gap = seam.gap_start_mm + (seam.gap_end_mm - seam.gap_start_mm) * np.asarray(fraction)
    along_s = abs(seam.end_mm[1] - seam.start_mm[1]) > abs(seam.end_mm[0] - seam.start_mm[0])
    if assembly.radius_mm is None or along_s:
        return gap
    heights = {p.id: p.height_mm for p in assembly.panels}
    mean_height = (heights[seam.panels[0]] + heights[seam.panels[1]]) / 2
    return gap * (assembly.radius_mm - mean_height) / assembly.radius_mm


def truth_of(assembly: Assembly, base_T_part: np.ndarray) -> Truth:
    """Every seam, junction, panel and defect of the assembly in the base frame (mm)."""
    heights = {p.id: p.height_mm for p in assembly.panels}

    def to_base(layout: np.ndarray, h: float | np.ndarray) -> Any:
        return _frozen(apply(base_T_part, layout_to_part(assembly, layout, np.asarray(h))).tolist())

    def normal_base(layout: np.ndarray) -> Point:
        return _frozen((layout_normal(assembly, layout) @ base_T_part[:3, :3].T).tolist())

    seams = []
    for seam in assembly.seams:
        mean_height = (heights[seam.panels[0]] + heights[seam.panels[1]]) / 2
        gaps = seam_gap_mm(assembly, seam, np.array([0.0, 1.0]))
        seams.append(
            TrueSeam(
                id=seam.id,
                panels=tuple(seam.panels),
                start=to_base(np.array(seam.start_mm), mean_height),
                end=to_base(np.array(seam.end_mm), mean_height),
                gap_start_mm=float(gaps[0]),
                gap_end_mm=float(gaps[1]),
                parallelism_mm=float(abs(gaps[1] - gaps[0])),
                step_mm=seam.step_mm,
            )
        )
    junctions = []
    for point, seam_ids in assembly.junctions:
        gaps = tuple(
            seams[i].gap_start_mm if assembly.seams[i].start_mm == point else seams[i].gap_end_mm
            for i in seam_ids
        )
        junctions.append(
            TrueJunction(
                at=to_base(np.array(point), 0.0),
                seams=tuple(seam_ids),
                gaps_mm=gaps,
                mismatch_mm=float(max(gaps) - min(gaps)),
            )
        )
    defects = []
    for panel in assembly.panels:
        for dent in panel.dents:
            centre = np.array(dent.centre_mm)
            defects.append(
                TrueDefect(
                    type=dent.kind,
                    panel=panel.id,
                    location=to_base(centre, panel.height_mm - dent.depth_mm),
                    normal=normal_base(centre),
                    depth_mm=abs(dent.depth_mm),
                    diameter_mm=2 * dent.radius_mm,
                )
            )
        for scratch in panel.scratches:
            a, b = np.array(scratch.start_mm), np.array(scratch.end_mm)
            centre = (a + b) / 2
            defects.append(
                TrueDefect(
                    type="scratch",
                    panel=panel.id,
                    location=to_base(centre, panel.height_mm),
                    normal=normal_base(centre),
                    start=to_base(a, panel.height_mm),
                    end=to_base(b, panel.height_mm),
                    depth_mm=scratch.depth_mm,
                    width_mm=scratch.width_mm,
                    length_mm=float(np.linalg.norm(b - a)),
                )
            )
        for patch in panel.patches:
            centre = np.array(patch.centre_mm)
            defects.append(
                TrueDefect(
                    type="color",
                    panel=panel.id,
                    location=to_base(centre, panel.height_mm),
                    normal=normal_base(centre),
                    delta_e=patch.delta_e,
                    area_mm2=float(np.pi * np.prod(patch.semi_axes_mm)),
                    diameter_mm=2 * float(max(patch.semi_axes_mm)),
                )
            )
    panels = tuple(
        TruePanel(
            id=p.id,
            corners=to_base(p.corners_mm, np.full(4, p.height_mm)),
            height_mm=p.height_mm,
            edge=TrueEdge(
                kind=p.edge.kind,
                size_mm=p.edge.size_mm,
                angle_deg=p.edge.angle_deg if p.edge.kind == "chamfer" else None,
                burr_mm=p.edge.burr_mm,
            ),
            area_mm2=_polygon_area(p.corners_mm),
        )
        for p in assembly.panels
    )
    return Truth(assembly.radius_mm, panels, tuple(seams), tuple(junctions), tuple(defects))


def _polygon_area(corners: np.ndarray) -> float:
    x, y = corners[:, 0], corners[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
