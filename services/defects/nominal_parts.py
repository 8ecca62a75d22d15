"""Parts with a nominal and a scan of the part as made, the truth known: a curved skin panel
(warped, dented), an angle profile (twisted) and a plate whose hole was drilled in the wrong
place. Each nominal is a triangle mesh of the part's scanned faces, outward normals, with
its faces named by region; the scan samples the part as made (the nominal with its
deviation field along the normals, a hole where it was drilled), with the scanner's noise,
outliers, an unscanned share, and lies in the scanner's frame (``nominal_T_cloud`` away).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from services.lib.pointcloud.mesh_distance import TriangleMesh
from services.lib.pointcloud.transforms import apply, from_rotvec, invert

PARTS = ("panel", "angle", "plate")


@dataclass(frozen=True)
class Dent:
    centre_mm: tuple[float, float, float]
    """On the nominal surface."""
    radius_mm: float
    depth_mm: float
    """Signed: negative into the part."""


@dataclass(frozen=True)
class NominalPart:
    name: str
    mesh: TriangleMesh
    region_of_face: np.ndarray
    """(F,) index into ``regions``."""
    regions: tuple[str, ...]
    points_mm: np.ndarray
    """The scan, in the scanner's frame."""
    deviation_mm: np.ndarray
    """(N,) each scan point's true signed distance to the nominal (outliers: NaN)."""
    nominal_T_cloud: np.ndarray
    dents: tuple[Dent, ...]
    warp_mm: float
    hole: dict | None = None
    """A mis-drilled hole: nominal and actual centre and radius."""


def make_part(
    name: str,
    *,
    seed: int = 0,
    spacing_mm: float = 0.5,
    noise_mm: float = 0.01,
    warp_mm: float = 0.3,
    unscanned_share: float = 0.2,
    outlier_share: float = 0.05,
    dents: int = 3,
    misalignment: tuple[float, float] = (3.0, 2.0),
) -> NominalPart:
    """One of ``PARTS`` scanned at ``spacing_mm`` with ``noise_mm`` 1σ; its true surface
    warped by up to ``warp_mm``, with ``dents`` dents; ``unscanned_share`` of its area
    never scanned, ``outlier_share`` of the points stray; the scan ``misalignment`` (mm,
    degrees) away from the nominal's frame."""
    if name not in PARTS:
        raise ValueError(f"no part {name!r}: one of {', '.join(PARTS)}")
    rng = np.random.default_rng(seed)
    mesh, region_of_face, regions, surface = _NOMINALS[name]()
    points, normals = _surface_samples(mesh, spacing_mm, rng)
    hole = None
    keep = np.ones(len(points), dtype=bool)
    extra = np.zeros((0, 3))
    if name == "plate":  # drilled 6 mm off: material where the nominal has its hole
        nominal_centre, actual_centre, radius = np.array([0.0, 0.0]), np.array([6.0, 0.0]), 10.0
        keep &= np.linalg.norm(points[:, :2] - actual_centre, axis=1) > radius
        filled = _disc_samples(nominal_centre, radius, spacing_mm, rng)
        filled = filled[np.linalg.norm(filled[:, :2] - actual_centre, axis=1) > radius]
        extra = filled
        hole = {"nominal_mm": [0, 0, 0], "actual_mm": [6, 0, 0], "radius_mm": radius}
    made_dents = _dents(mesh, region_of_face, surface, dents, rng)
    field = _deviation(points, normals, surface, warp_mm, made_dents)
    actual = points + field[:, None] * normals
    deviation = field.copy()
    actual, deviation = actual[keep], deviation[keep]
    if len(extra):
        actual = np.vstack([actual, extra])
        deviation = np.concatenate([deviation, np.full(len(extra), np.nan)])  # measured later
    # an unscanned share: the far end along x (the longest side of every part)
    seen = actual[:, 0] < np.quantile(actual[:, 0], 1.0 - unscanned_share)
    actual, deviation = actual[seen], deviation[seen]
    actual = actual + rng.normal(0, noise_mm, actual.shape)
    strays = int(outlier_share * len(actual))
    if strays:
        low, high = actual.min(axis=0) - 5, actual.max(axis=0) + 5
        actual = np.vstack([actual, rng.uniform(low, high, (strays, 3))])
        deviation = np.concatenate([deviation, np.full(strays, np.nan)])
    rng.permutation(len(actual))  # drawn still: each seed makes the part the README measured
    order = np.lexsort(  # a real scan's order: along its lines
        (actual[:, 0], np.round(actual[:, 1] / spacing_mm))
    )
    rotvec = rng.normal(size=3)
    rotvec *= np.radians(misalignment[1]) / np.linalg.norm(rotvec)
    shift = rng.normal(size=3)
    shift *= misalignment[0] / np.linalg.norm(shift)
    nominal_T_cloud = from_rotvec(rotvec, shift)
    return NominalPart(
        name,
        mesh,
        region_of_face,
        regions,
        apply(invert(nominal_T_cloud), actual[order]),
        deviation[order],
        nominal_T_cloud,
        made_dents,
        warp_mm,
        hole,
    )


def grid_sheet(u: np.ndarray, v: np.ndarray, to_xyz) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    """A grid sheet: vertices ``to_xyz(u, v)`` over the grid of u × v, two faces a cell,
    counter-clockwise seen from +normal (u × v direction)."""
    gu, gv = np.meshgrid(u, v, indexing="ij")
    vertices = to_xyz(gu.ravel(), gv.ravel())
    rows, cols = len(u), len(v)
    cell = (np.arange(rows - 1)[:, None] * cols + np.arange(cols - 1)[None, :]).ravel()
    faces = np.vstack(
        [
            np.column_stack([cell, cell + cols, cell + cols + 1]),
            np.column_stack([cell, cell + cols + 1, cell + 1]),
        ]
    )
    return vertices, faces


def _panel() -> tuple:
    """A fuselage skin panel: a 600 × 400 mm patch of a 1 m radius cylinder, outside up,
    with its 3 mm trimmed edges."""
    radius = 1000.0

    def xyz(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        angle = u / radius
        return np.column_stack([radius * np.sin(angle), v, radius * np.cos(angle) - radius])

    vertices, faces = grid_sheet(np.linspace(-300, 300, 241), np.linspace(-200, 200, 161), xyz)
    return _with_walls(vertices, faces, (241, 161), 3.0, ("skin", "edges"), "panel")


def _angle() -> tuple:
    """An angle profile 500 mm long: a 60 mm flange (z up) and a 40 mm web (-y out), its
    outer faces and its two 3 mm thick ends."""
    length = np.linspace(0, 500, 201)
    flange, ff = grid_sheet(
        length, np.linspace(0, 60, 25), lambda x, y: np.column_stack([x, y, 0 * x])
    )
    web, wf = grid_sheet(
        length, np.linspace(0, 40, 17), lambda x, z: np.column_stack([x, 0 * x, -z])
    )
    wf = wf[:, ::-1]
    ends = []
    for x in (0.0, 500.0):
        ends += [
            [[x, 0, 0], [x, 60, 0], [x, 60, -3], [x, 0, -3]],
            [[x, 0, 0], [x, 3, 0], [x, 3, -40], [x, 0, -40]],
        ]
    quads = np.array(ends, float)
    end_vertices = quads.reshape(-1, 3)
    base = len(flange) + len(web) + 4 * np.arange(len(quads))
    end_faces = np.vstack(
        [np.column_stack([base, base + 1, base + 2]), np.column_stack([base, base + 2, base + 3])]
    )
    centre = np.array([250.0, 30.0, -20.0])
    end_faces = _outward(np.vstack([flange, web, end_vertices]), end_faces, centre)
    vertices = np.vstack([flange, web, end_vertices])
    faces = np.vstack([ff, wf + len(flange), end_faces])
    region = np.concatenate(
        [np.zeros(len(ff), np.int64), np.ones(len(wf), np.int64), np.full(len(end_faces), 2)]
    )
    return TriangleMesh(vertices, faces), region, ("flange", "web", "ends"), "angle"


def _plate() -> tuple:
    """A 300 × 200 mm plate's top with a 20 mm hole at its centre (its wall follows the
    top's grid round it), and its 5 mm edges."""
    vertices, faces = grid_sheet(
        np.linspace(-150, 150, 151), np.linspace(-100, 100, 101),
        lambda x, y: np.column_stack([x, y, 0 * x]),
    )  # fmt: skip
    mesh, region, regions, surface = _with_walls(
        vertices, faces, (151, 101), 5.0, ("top", "edges"), "plate"
    )
    vertices = np.asarray(mesh.vertices_mm)
    keep = (region == 1) | (np.linalg.norm(vertices[mesh.faces].mean(axis=1)[:, :2], axis=1) > 10.0)
    faces, region = mesh.faces[keep], region[keep]
    # the hole's wall: the top's border round the hole (edges of one face) drawn 5 mm down
    edges = faces[region == 0][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.sort(edges, axis=1)
    _, first, uses = np.unique(key, axis=0, return_index=True, return_counts=True)
    rim = edges[first[uses == 1]]
    rim = rim[np.linalg.norm(vertices[rim].mean(axis=1)[:, :2], axis=1) < 20.0]
    below = len(vertices) + np.arange(2 * len(rim)).reshape(-1, 2)
    lowered = vertices[rim.ravel()] - [0.0, 0.0, 5.0]
    wall = np.vstack([np.column_stack([rim[:, 0], below[:, 0], rim[:, 1]]),
                      np.column_stack([rim[:, 1], below[:, 0], below[:, 1]])])  # fmt: skip
    everything = np.vstack([vertices, lowered])
    corners = everything[wall]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normal[:, :2], -corners.mean(axis=1)[:, :2]) < 0
    wall[inward] = wall[inward][:, ::-1]  # out of the material: towards the hole's axis
    faces = np.vstack([faces, wall])
    region = np.concatenate([region, np.full(len(wall), 2)])
    return TriangleMesh(everything, faces), region, ("top", "edges", "hole"), surface


def _with_walls(vertices: np.ndarray, faces: np.ndarray, shape: tuple[int, int], depth: float,
                regions: tuple[str, str], surface: str) -> tuple:  # fmt: skip
    """A grid sheet with walls ``depth`` deep down its border (straight down -z)."""
    rows, cols = shape
    index = np.arange(rows * cols).reshape(rows, cols)
    loop = np.concatenate([index[0, :], index[1:, -1], index[-1, -2::-1], index[-2:0:-1, 0]])
    top = vertices[loop]
    bottom = top - np.array([0.0, 0.0, depth])
    base = len(vertices)
    following = np.roll(np.arange(len(loop)), -1)
    a, b = loop, loop[following]
    c, d = base + following, base + np.arange(len(loop))
    walls = np.vstack([np.column_stack([a, d, c]), np.column_stack([a, c, b])])
    everything = np.vstack([vertices, bottom])
    walls = _outward(everything, walls, vertices.mean(axis=0))
    region = np.concatenate([np.zeros(len(faces), np.int64), np.ones(len(walls), np.int64)])
    return TriangleMesh(everything, np.vstack([faces, walls])), region, regions, surface


def _outward(vertices: np.ndarray, faces: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``faces`` turned where needed so their normals point away from ``centre`` (in the
    horizontal plane for walls)."""
    corners = vertices[faces]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    away = corners.mean(axis=1) - centre
    away[:, 2] = 0 if np.abs(normal[:, 2]).max() < 1e-9 else away[:, 2]
    flip = np.einsum("ij,ij->i", normal, away) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return faces


_NOMINALS = {"panel": _panel, "angle": _angle, "plate": _plate}


def _surface_samples(mesh: TriangleMesh, spacing_mm: float, rng: np.random.Generator):  # noqa: ANN202
    """Points spread evenly over the mesh (one per spacing² of area), their face normal."""
    corners = np.asarray(mesh.vertices_mm)[mesh.faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    count = int(area.sum() / spacing_mm**2)
    face = rng.choice(len(area), count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    c = corners[face]
    points = c[:, 0] + r1[:, None] * (c[:, 1] - c[:, 0]) + r2[:, None] * (c[:, 2] - c[:, 0])
    normals = cross[face] / (2 * area[face])[:, None]
    return points, normals


def _disc_samples(
    centre: np.ndarray, radius: float, spacing: float, rng: np.random.Generator
) -> np.ndarray:
    count = int(np.pi * radius**2 / spacing**2)
    r = radius * np.sqrt(rng.random(count))
    angle = rng.uniform(0, 2 * np.pi, count)
    return np.column_stack(
        [centre[0] + r * np.cos(angle), centre[1] + r * np.sin(angle), np.zeros(count)]
    )


def _dents(
    mesh: TriangleMesh,
    region_of_face: np.ndarray,
    surface: str,
    count: int,
    rng: np.random.Generator,
) -> tuple[Dent, ...]:
    """Dents on the part's main face (its region 0: the skin, the flange, the plate's top),
    10–70 % along x (clear of the unscanned end) and 15–85 % across, clear of the hole."""
    top = np.asarray(mesh.vertices_mm)[np.unique(mesh.faces[region_of_face == 0])]
    low, high = top.min(axis=0), top.max(axis=0)
    made = []
    while len(made) < count:
        share = np.array([rng.uniform(0.1, 0.7), rng.uniform(0.15, 0.85)])
        target = low[:2] + share * (high[:2] - low[:2])
        centre = top[np.argmin(np.linalg.norm(top[:, :2] - target, axis=1))]
        if surface == "plate" and np.linalg.norm(centre[:2]) < 35.0:
            continue
        made.append(Dent(tuple(float(c) for c in centre), float(rng.uniform(6, 15)),
                         -float(rng.uniform(0.3, 1.0))))  # fmt: skip
    return tuple(made)


def _deviation(points: np.ndarray, normals: np.ndarray, surface: str, warp_mm: float,
               dents: tuple[Dent, ...]) -> np.ndarray:  # fmt: skip
    """Each nominal surface point's true normal offset: the warp (a panel's bow, an angle's
    twist) and the dents (raised-cosine caps)."""
    if surface == "angle":  # twisted: the far end turned so that its flange's tip moves warp_mm
        turn = warp_mm / 60.0 * points[:, 0] / 500.0
        moved = points.copy()
        moved[:, 1] = points[:, 1] * np.cos(turn) - points[:, 2] * np.sin(turn)
        moved[:, 2] = points[:, 1] * np.sin(turn) + points[:, 2] * np.cos(turn)
        field = np.einsum("ij,ij->i", moved - points, normals)
    else:  # bowed: up to warp_mm at the middle, none at the edges
        span = np.ptp(points[:, :2], axis=0)
        u = (points[:, :2] - points[:, :2].min(axis=0)) / span
        field = warp_mm * np.sin(np.pi * u[:, 0]) * np.sin(np.pi * u[:, 1])
    for dent in dents:
        r = np.linalg.norm(points - np.array(dent.centre_mm), axis=1)
        inside = r < dent.radius_mm
        field[inside] += dent.depth_mm * 0.5 * (1 + np.cos(np.pi * r[inside] / dent.radius_mm))
    return field


def part_shape(name: str) -> object:
    """The part's nominal solid as Open CASCADE builds it (the meshes above are its
    scanned faces): the skin panel a 3 mm shell of the 1 m cylinder, the angle its L
    section drawn along 500 mm, the plate a 5 mm block with its 20 mm hole."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakePolygon
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCylinder, BRepPrimAPI_MakePrism
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt, gp_Vec

    if name == "panel":
        radius, span = 1000.0, 0.6
        axis = gp_Ax2(gp_Pnt(0, -200, -radius), gp_Dir(0, 1, 0),
                      gp_Dir(np.sin(-span / 2), 0, np.cos(-span / 2)))  # fmt: skip
        outer = BRepPrimAPI_MakeCylinder(axis, radius, 400, span).Shape()
        inner = BRepPrimAPI_MakeCylinder(axis, radius - 3, 400, span).Shape()
        return BRepAlgoAPI_Cut(outer, inner).Shape()
    if name == "angle":
        outline = BRepBuilderAPI_MakePolygon()
        for corner in ((0, 0, 0), (0, 60, 0), (0, 60, -3), (0, 3, -3), (0, 3, -40), (0, 0, -40)):
            outline.Add(gp_Pnt(*corner))
        outline.Close()
        section = BRepBuilderAPI_MakeFace(outline.Wire()).Face()
        return BRepPrimAPI_MakePrism(section, gp_Vec(500, 0, 0)).Shape()
    block = BRepPrimAPI_MakeBox(gp_Pnt(-150, -100, -5), 300, 200, 5).Shape()
    drill = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(0, 0, -10), gp_Dir(0, 0, 1)), 10, 20).Shape()
    return BRepAlgoAPI_Cut(block, drill).Shape()


def write_part(folder: Path, part: NominalPart) -> list[Path]:
    """The part's scan (cloud.ply, the scanner's frame), nominal (nominal.stl, its regions
    as solids; nominal.step where Open CASCADE is installed), truth.json (the pose, the
    dents, the hole) and points.json (reference points, as `--reference-points` reads
    them)."""
    from services.lib.pointcloud.ply import PointCloud, write_ply
    from services.lib.pointcloud.step import available, write_step
    from services.lib.pointcloud.stl import write_stl
    from services.lib.pointcloud.transforms import to_json

    folder.mkdir(parents=True, exist_ok=True)
    written = [folder / "cloud.ply", folder / "nominal.stl", folder / "truth.json"]
    write_ply(written[0], PointCloud(part.points_mm.astype(np.float32)),
              comments=(f"vista simulated {part.name}, scanner frame, mm",))  # fmt: skip
    write_stl(written[1], part.mesh, binary=False, region_of_face=part.region_of_face,
              regions=part.regions)  # fmt: skip
    truth = {
        "part": part.name,
        "nominal_T_cloud": to_json(part.nominal_T_cloud),
        "warp_mm": part.warp_mm,
        "dents": [asdict(d) for d in part.dents],
        "hole": part.hole,
    }
    written[2].write_text(json.dumps(truth, indent=1) + "\n")
    written.append(folder / "points.json")
    written[-1].write_text(json.dumps(reference_points(part), indent=1) + "\n")
    if available():
        write_step(folder / "nominal.step", part_shape(part.name))
        written.append(folder / "nominal.step")
    return written


PICK_MM = 0.05
"""1σ of a reference point picked on the scan (a probed or targeted point)."""


def reference_points(part: NominalPart, seed: int = 0) -> dict:
    """Four reference points: the corners of the nominal's box nearest to its vertices on
    the part (named A–D), and the same points as picked on the scan (in its frame, with
    ``PICK_MM`` of picking error)."""
    vertices = np.asarray(part.mesh.vertices_mm)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    targets = [low, [high[0], low[1], low[2]], [low[0], high[1], low[2]], high]
    chosen = [vertices[np.argmin(np.linalg.norm(vertices - t, axis=1))] for t in targets]
    picked = apply(invert(part.nominal_T_cloud), np.array(chosen))
    picked += np.random.default_rng(seed).normal(0, PICK_MM, picked.shape)
    names = "ABCD"
    return {
        "nominal": {n: np.round(c, 4).tolist() for n, c in zip(names, chosen, strict=True)},
        "scan": {n: np.round(c, 4).tolist() for n, c in zip(names, picked, strict=True)},
    }
