"""Simulated panel assemblies with known seams and surface defects, scanned through the
stitching simulator's sensor model.

Panels are laid out in a grid on a *layout plane* (x, s) in mm: flat, or wrapped onto a
concave cylinder of radius ``radius_mm`` whose axis runs along x (a sidewall seen from the
cabin; s is the arc length across it). A point (x, s) at height h (along the surface
normal, towards the viewer) maps to the part frame {P} as

    flat:    (x, s, h)
    curved:  (x, (R − h) sin(s/R), R − (R − h) cos(s/R))

Each panel is a quadrilateral whose four edges come from its seams, so a seam's two
edges need not be parallel (taper); its top is offset by the panel's height (steps) and
its edges fall to a vertical side face along their ``EdgeProfile``: rounded (an arc of any
radius), chamfered (a straight face at an angle) or square, optionally with a burr (a lip
standing above the top at the edge). A backing structure lies ``backing_depth_mm`` below,
visible through wide gaps.

Surface defects are analytic displacements along the normal (dents, bumps, scratches)
and colour changes (patches) of the panel top; they are applied to the ray hits, so they
keep their full resolution whatever the mesh's. Ground truth is exact: every seam's gap at
both ends, its step, every junction's gaps and every defect's size and place.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.lib.pointcloud.color import lab_to_srgb, srgb_to_lab
from services.lib.pointcloud.scan_sim import Mesh, Scanner, SensorModel
from services.lib.pointcloud.transforms import apply, invert

ARC_SAMPLES = 24
"""Vertices on a rounded edge's quarter circle (chord sag ≤ 0.0012 × the radius)."""
INTERIOR_STEP_MM = 2.0
EDGE_SEEN_MM = 0.05
"""A corner (or a chamfer's foot) counts as seen where a view returns a point this close
to it: the extent rule then places it within about that."""
PANEL_LAB = (86.0, 0.5, 6.0)
"""Cabin lining off-white."""
BACKING_LAB = (35.0, 0.0, 0.0)


@dataclass(frozen=True)
class Dent:
    """A rounded dent (``depth_mm`` > 0 into the panel) or bump (``depth_mm`` < 0):
    a raised-cosine profile reaching zero at ``radius_mm``."""

    centre_mm: tuple[float, float]
    radius_mm: float
    depth_mm: float

    @property
    def kind(self) -> str:
        return "dent" if self.depth_mm > 0 else "bump"


@dataclass(frozen=True)
class Scratch:
    """A straight groove with a parabolic section ``width_mm`` wide, ``depth_mm`` deep,
    ramping in over one width at each end."""

    start_mm: tuple[float, float]
    end_mm: tuple[float, float]
    width_mm: float
    depth_mm: float


@dataclass(frozen=True)
class ColorPatch:
    """An elliptical patch that shifts the colour by ``delta_lab`` (ΔE = its norm), with a
    soft rim over the outer 15 % of its semi-axes."""

    centre_mm: tuple[float, float]
    semi_axes_mm: tuple[float, float]
    angle_deg: float
    delta_lab: tuple[float, float, float]

    @property
    def delta_e(self) -> float:
        return float(np.linalg.norm(self.delta_lab))


EDGE_KINDS = ("round", "chamfer", "square")


@dataclass(frozen=True)
class EdgeProfile:
    """How a panel's top falls to its vertical side face, which stands on the panel's
    outline (so the profile never changes a gap): ``round`` — a quarter circle of radius
    ``size_mm`` tangent to the top; ``chamfer`` — a straight face ``size_mm`` wide across,
    sloping down at ``angle_deg``; ``square`` — the top runs to the side face. A burr is a
    lip ``burr_mm`` high on the top at the outline, falling to the top over
    ``burr_width_mm``."""

    kind: str = "round"
    size_mm: float = 1.0
    angle_deg: float = 45.0
    burr_mm: float = 0.0
    burr_width_mm: float = 0.15

    def __post_init__(self) -> None:
        if self.kind not in EDGE_KINDS:
            raise ValueError(f"edge kind: one of {EDGE_KINDS}, not {self.kind!r}")

    @property
    def depth_mm(self) -> float:
        """How far below the top the profile meets the side face."""
        if self.kind == "round":
            return self.size_mm
        if self.kind == "chamfer":
            return self.size_mm * float(np.tan(np.radians(self.angle_deg)))
        return 0.0

    @property
    def width_mm(self) -> float:
        """How far from the outline the profile leaves the top (0 for a square edge)."""
        return 0.0 if self.kind == "square" else self.size_mm

    def height_mm(self, distance_mm: np.ndarray) -> np.ndarray:
        """(…,) height relative to the top at ``distance_mm`` ≥ 0 inside the outline."""
        d = np.asarray(distance_mm, dtype=np.float64)
        inside = np.clip(self.width_mm - d, 0.0, self.width_mm)
        if self.kind == "round":
            r = self.size_mm
            drop = r - np.sqrt(r * r - inside * inside)
        else:
            drop = inside * np.tan(np.radians(self.angle_deg)) if self.kind == "chamfer" else 0 * d
        lip = self.burr_mm * np.clip(1 - d / self.burr_width_mm, 0.0, 1.0) if self.burr_mm else 0
        return lip - drop

    def samples_mm(self) -> np.ndarray:
        """Distances from the outline where a mesh needs vertices to follow the profile."""
        if self.kind == "round":
            phi = np.linspace(np.pi / 2, 0.0, ARC_SAMPLES)
            profile = self.size_mm * (1 - np.sin(phi))
        else:
            profile = np.array([0.0, self.width_mm])
        burr = [0.0, self.burr_width_mm] if self.burr_mm else []
        return np.unique(np.concatenate([profile, burr]))


@dataclass(frozen=True)
class DarkPatch:
    """A dark or shiny spot (tape, a glossy label) the sensor sees badly: inside
    ``radius_mm`` of ``centre_mm`` (layout), a pixel returns nothing with probability
    ``hole_fraction`` and a spike (a glint) with probability ``spike_fraction``."""

    centre_mm: tuple[float, float]
    radius_mm: float
    hole_fraction: float = 0.6
    spike_fraction: float = 0.05


@dataclass(frozen=True)
class Panel:
    id: int
    corners_mm: np.ndarray
    """(4, 2) layout (x, s) corners, counter-clockwise from the lowest x, s."""
    height_mm: float
    edge: EdgeProfile
    dents: tuple[Dent, ...] = ()
    scratches: tuple[Scratch, ...] = ()
    patches: tuple[ColorPatch, ...] = ()
    lab: tuple[float, float, float] = PANEL_LAB


@dataclass(frozen=True)
class SeamTruth:
    id: int
    panels: tuple[int, int]
    """(a, b): b lies on the +across side; step = height of b − height of a."""
    start_mm: tuple[float, float]
    end_mm: tuple[float, float]
    """Layout ends of the seam's centre line (junction points or the assembly's rim)."""
    gap_start_mm: float
    gap_end_mm: float
    step_mm: float


@dataclass(frozen=True)
class Assembly:
    panels: tuple[Panel, ...]
    seams: tuple[SeamTruth, ...]
    junctions: tuple[tuple[tuple[float, float], tuple[int, ...]], ...]
    """(layout point, ids of the seams meeting there)."""
    radius_mm: float | None = None
    thickness_mm: float = 3.0
    backing_depth_mm: float = 20.0
    texture_delta_e: float = 0.6
    """1σ per-point colour noise of the lining's texture."""
    dark_patches: tuple[DarkPatch, ...] = ()


# --- layout ------------------------------------------------------------------------------


def _intersect(p: np.ndarray, d: np.ndarray, q: np.ndarray, e: np.ndarray) -> np.ndarray:
    t = np.linalg.solve(np.stack([d, -e], 1), q - p)
    return p + t[0] * d


@dataclass(frozen=True)
class AssemblySpec:
    """What to draw for a random assembly; ranges are sampled uniformly."""

    rows: int = 2
    cols: int = 2
    panel_mm: tuple[float, float] = (150.0, 100.0)
    radius_mm: float | None = None
    gap_mm: tuple[float, float] = (0.3, 6.0)
    step_mm: tuple[float, float] = (-3.0, 3.0)
    taper_mm: tuple[float, float] = (0.0, 1.0)
    edge_radius_mm: tuple[float, float] = (0.5, 2.0)
    edge_kinds: tuple[str, ...] = ("round",)
    """Each panel's edge is one of these kinds, drawn uniformly."""
    chamfer_mm: tuple[float, float] = (0.3, 1.0)
    chamfer_angle_deg: float = 45.0
    burr_mm: tuple[float, float] = (0.0, 0.0)
    """Height of the burr on square edges (cut edges)."""
    dark_patches: int = 0
    """Dark or shiny patches (holes and glints), each centred on a random seam."""
    dents: int = 1
    bumps: int = 1
    scratches: int = 1
    patches: int = 1
    dent_radius_mm: tuple[float, float] = (2.0, 20.0)
    dent_depth_mm: tuple[float, float] = (0.2, 2.0)
    scratch_length_mm: tuple[float, float] = (5.0, 50.0)
    scratch_width_mm: tuple[float, float] = (0.1, 1.0)
    scratch_depth_mm: tuple[float, float] = (0.1, 0.5)
    patch_delta_e: tuple[float, float] = (5.0, 20.0)
    patch_size_mm: tuple[float, float] = (4.0, 20.0)


def random_assembly(spec: AssemblySpec, rng: np.random.Generator) -> Assembly:
    """A rows × cols grid of panels with random seams (gap at each end, hence taper; step;
    edge radius) and ``spec.dents`` dents, … on every panel."""
    if not 2 <= spec.rows * spec.cols <= 12:
        raise ValueError("an assembly has 2 to 12 panels")
    width, height = spec.panel_mm
    xs, ss = width * np.arange(spec.cols + 1), height * np.arange(spec.rows + 1)
    cells = [(i, j) for i in range(spec.rows) for j in range(spec.cols)]
    index = {cell: k for k, cell in enumerate(cells)}
    heights = rng.uniform(spec.step_mm[0] / 2, spec.step_mm[1] / 2, (spec.rows, spec.cols))
    # Every panel edge as a line (point, direction); the rim's edges stay on the grid.
    edges = {}
    for i, j in cells:
        edges[i, j, "left"] = (np.array([xs[j], ss[i]]), np.array([0.0, 1.0]))
        edges[i, j, "right"] = (np.array([xs[j + 1], ss[i]]), np.array([0.0, 1.0]))
        edges[i, j, "bottom"] = (np.array([xs[j], ss[i]]), np.array([1.0, 0.0]))
        edges[i, j, "top"] = (np.array([xs[j], ss[i + 1]]), np.array([1.0, 0.0]))
    seams: list[SeamTruth] = []

    def add_seam(a: tuple, b: tuple, start: np.ndarray, end: np.ndarray, sides: tuple) -> None:
        g0 = rng.uniform(*spec.gap_mm)
        taper = rng.choice([-1.0, 1.0]) * rng.uniform(*spec.taper_mm)
        g1 = float(np.clip(g0 + taper, *spec.gap_mm))
        across = np.array([[0.0, -1.0], [1.0, 0.0]]) @ (end - start) / np.linalg.norm(end - start)
        a0, a1 = start - across * g0 / 2, end - across * g1 / 2
        b0, b1 = start + across * g0 / 2, end + across * g1 / 2
        edges[(*a, sides[0])] = (a0, a1 - a0)
        edges[(*b, sides[1])] = (b0, b1 - b0)
        step = float(heights[b] - heights[a])
        seams.append(
            SeamTruth(
                len(seams),
                (index[a], index[b]),
                (float(start[0]), float(start[1])),
                (float(end[0]), float(end[1])),
                g0,
                g1,
                step,
            )
        )

    for i, j in cells:
        # across = the seam direction turned +90°, so the second panel lies on its + side
        if j + 1 < spec.cols:  # running along −s: across = +x
            start, end = np.array([xs[j + 1], ss[i + 1]]), np.array([xs[j + 1], ss[i]])
            add_seam((i, j), (i, j + 1), start, end, ("right", "left"))
        if i + 1 < spec.rows:  # running along +x: across = +s
            start, end = np.array([xs[j], ss[i + 1]]), np.array([xs[j + 1], ss[i + 1]])
            add_seam((i, j), (i + 1, j), start, end, ("top", "bottom"))
    panels = []
    for i, j in cells:
        left, bottom = edges[i, j, "left"], edges[i, j, "bottom"]
        right, top = edges[i, j, "right"], edges[i, j, "top"]
        corners = np.array(
            [
                _intersect(*left, *bottom),
                _intersect(*bottom, *right),
                _intersect(*right, *top),
                _intersect(*top, *left),
            ]
        )
        edge = _random_edge(spec, rng)
        defects = _random_defects(spec, corners, margin_mm=edge.width_mm + 8.0, rng=rng)
        panels.append(Panel(index[i, j], corners, float(heights[i, j]), edge, *defects))
    junctions = []
    for i in range(1, spec.rows):
        for j in range(1, spec.cols):
            point = (float(xs[j]), float(ss[i]))
            meeting = tuple(s.id for s in seams if point in (s.start_mm, s.end_mm))
            junctions.append((point, meeting))
    dark = []
    for _ in range(spec.dark_patches):
        seam = seams[int(rng.integers(len(seams)))]
        start, end = np.array(seam.start_mm), np.array(seam.end_mm)
        centre = start + rng.uniform(0.25, 0.75) * (end - start)
        dark.append(DarkPatch(tuple(float(c) for c in centre), float(rng.uniform(5.0, 12.0))))
    return Assembly(
        tuple(panels),
        tuple(seams),
        tuple(junctions),
        radius_mm=spec.radius_mm,
        dark_patches=tuple(dark),
    )


def _random_edge(spec: AssemblySpec, rng: np.random.Generator) -> EdgeProfile:
    """One panel's edge profile (the same draws as ever for the default round edges)."""
    kinds = spec.edge_kinds
    kind = kinds[int(rng.integers(len(kinds)))] if len(kinds) > 1 else kinds[0]
    size = {
        "round": lambda: rng.uniform(*spec.edge_radius_mm),
        "chamfer": lambda: rng.uniform(*spec.chamfer_mm),
        "square": lambda: 0.0,
    }[kind]()
    burr = float(rng.uniform(*spec.burr_mm)) if spec.burr_mm[1] > 0 else 0.0
    # A burr is what cutting leaves on a square edge; a chamfer or a radius takes it off.
    return EdgeProfile(kind, float(size), spec.chamfer_angle_deg, burr if kind == "square" else 0.0)


def _random_defects(
    spec: AssemblySpec, corners: np.ndarray, *, margin_mm: float, rng: np.random.Generator
) -> tuple[tuple[Dent, ...], tuple[Scratch, ...], tuple[ColorPatch, ...]]:
    """Defects placed inside the panel, ``margin_mm`` from its edges, apart from each other."""
    low, high = corners.min(0) + margin_mm, corners.max(0) - margin_mm
    taken: list[tuple[np.ndarray, float]] = []

    def place(size_mm: float) -> np.ndarray | None:
        for _ in range(200):
            lo, hi = low + size_mm, high - size_mm
            if np.any(hi <= lo):
                return None
            centre = rng.uniform(lo, hi)
            if all(np.linalg.norm(centre - c) > size_mm + r + 4.0 for c, r in taken):
                taken.append((centre, size_mm))
                return centre
        return None

    dents = []
    for count, sign in ((spec.dents, 1.0), (spec.bumps, -1.0)):
        for _ in range(count):
            radius = rng.uniform(*spec.dent_radius_mm)
            centre = place(radius)
            if centre is not None:
                depth = sign * rng.uniform(*spec.dent_depth_mm)
                dents.append(Dent(tuple(centre), float(radius), float(depth)))
    scratches = []
    for _ in range(spec.scratches):
        length = rng.uniform(*spec.scratch_length_mm)
        centre = place(length / 2)
        if centre is not None:
            angle = rng.uniform(0, np.pi)
            half = length / 2 * np.array([np.cos(angle), np.sin(angle)])
            scratches.append(
                Scratch(
                    tuple(centre - half),
                    tuple(centre + half),
                    float(rng.uniform(*spec.scratch_width_mm)),
                    float(rng.uniform(*spec.scratch_depth_mm)),
                )
            )
    patches = []
    for _ in range(spec.patches):
        axes = rng.uniform(*spec.patch_size_mm, 2) / 2
        centre = place(float(axes.max()))
        if centre is not None:
            delta = _in_gamut_shift(rng.uniform(*spec.patch_delta_e), rng)
            patches.append(
                ColorPatch(tuple(centre), tuple(axes), float(rng.uniform(0, 180)), tuple(delta))
            )
    return tuple(dents), tuple(scratches), tuple(patches)


def _in_gamut_shift(delta_e: float, rng: np.random.Generator) -> np.ndarray:
    """A random L*a*b* shift of size ``delta_e`` that the lining colour survives in 8-bit
    sRGB (no clipping), so the patch's ΔE is what a camera can record."""
    base = np.array(PANEL_LAB)
    for _ in range(1000):
        direction = rng.normal(size=3)
        delta = direction / np.linalg.norm(direction) * delta_e
        shown = srgb_to_lab(lab_to_srgb(base + delta)) - srgb_to_lab(lab_to_srgb(base))
        if abs(np.linalg.norm(shown) - delta_e) < 0.3:
            return delta
    raise ValueError(f"no in-gamut colour shift of ΔE {delta_e} from {PANEL_LAB}")


# --- geometry ----------------------------------------------------------------------------


def layout_to_part(assembly: Assembly, xs: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(…, 2) layout points (x, s) at heights h (…,) → (…, 3) part-frame points, mm."""
    x, s = xs[..., 0], xs[..., 1]
    radius = assembly.radius_mm
    if radius is None:
        return np.stack([x, s, h], -1)
    angle = s / radius
    return np.stack([x, (radius - h) * np.sin(angle), radius - (radius - h) * np.cos(angle)], -1)


def part_to_layout(assembly: Assembly, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) part-frame points → ((N, 2) layout (x, s), (N,) height h)."""
    radius = assembly.radius_mm
    if radius is None:
        return points[:, :2].copy(), points[:, 2].copy()
    y, z = points[:, 1], radius - points[:, 2]
    layout = np.stack([points[:, 0], radius * np.arctan2(y, z)], -1)
    return layout, radius - np.hypot(y, z)


def layout_normal(assembly: Assembly, xs: np.ndarray) -> np.ndarray:
    """(…, 3) unit surface normal (towards the viewer) at layout points (…, 2)."""
    s = xs[..., 1]
    if assembly.radius_mm is None:
        return np.stack([np.zeros_like(s), np.zeros_like(s), np.ones_like(s)], -1)
    angle = s / assembly.radius_mm
    return np.stack([np.zeros_like(s), -np.sin(angle), np.cos(angle)], -1)


def edge_distance_mm(panel: Panel, xs: np.ndarray) -> np.ndarray:
    """(…,) distance from layout points to the panel's nearest edge, > 0 inside."""
    corners = panel.corners_mm
    distances = []
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        direction = (b - a) / np.linalg.norm(b - a)
        inward = np.array([-direction[1], direction[0]])  # corners run counter-clockwise
        distances.append((xs - a) @ inward)
    return np.min(distances, axis=0)


def _edge_fractions(span_mm: float, edge: EdgeProfile) -> np.ndarray:
    """Sample positions (fractions of ``span_mm``) along the edge profile at both ends."""
    profile = edge.samples_mm()
    inner = np.arange(profile.max() + INTERIOR_STEP_MM, span_mm / 2, INTERIOR_STEP_MM)
    half = np.concatenate([profile, inner]) / span_mm
    return np.unique(np.concatenate([half, 1 - half, [0.5]]))


def _grid_faces(rows: int, cols: int, offset: int) -> np.ndarray:
    index = offset + np.arange(rows * cols).reshape(rows, cols)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])


def panel_mesh(assembly: Assembly, panel: Panel) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) part frame, faces (F, 3)) of the panel top, its edge profile and a
    vertical side face down to the panel's thickness (the defects are not in the mesh)."""
    corners = panel.corners_mm
    span = np.linalg.norm(corners[1] - corners[0]), np.linalg.norm(corners[3] - corners[0])
    p = _edge_fractions(span[0], panel.edge)
    q = _edge_fractions(span[1], panel.edge)
    p, q = np.concatenate([[0.0], p, [1.0]]), np.concatenate([[0.0], q, [1.0]])
    pp, qq = np.meshgrid(p, q, indexing="ij")
    layout = (
        (1 - pp)[..., None] * (1 - qq)[..., None] * corners[0]
        + pp[..., None] * (1 - qq)[..., None] * corners[1]
        + pp[..., None] * qq[..., None] * corners[2]
        + (1 - pp)[..., None] * qq[..., None] * corners[3]
    )
    h = panel.height_mm + panel.edge.height_mm(np.maximum(edge_distance_mm(panel, layout), 0.0))
    skirt = np.zeros(pp.shape, dtype=bool)
    skirt[[0, -1], :] = True
    skirt[:, [0, -1]] = True
    # The side face runs down to the panel's thickness, or 1 mm below the edge's foot where
    # the edge drops deeper (a 5 mm arc on a 3 mm sheet): never back up into the edge.
    depth = max(assembly.thickness_mm, panel.edge.depth_mm + 1.0)
    h = np.where(skirt, panel.height_mm - depth, h)
    vertices = layout_to_part(assembly, layout, h).reshape(-1, 3)
    return vertices, _grid_faces(len(p), len(q), 0)


def assembly_mesh(assembly: Assembly) -> tuple[Mesh, np.ndarray]:
    """The whole assembly and its backing as one mesh, and (F,) the panel id of each face
    (−1 for the backing)."""
    vertices, faces, owner = [], [], []
    count = 0
    for panel in assembly.panels:
        v, f = panel_mesh(assembly, panel)
        vertices.append(v)
        faces.append(f + count)
        owner.append(np.full(len(f), panel.id))
        count += len(v)
    low = np.min([p.corners_mm.min(0) for p in assembly.panels], axis=0) - 10.0
    high = np.max([p.corners_mm.max(0) for p in assembly.panels], axis=0) + 10.0
    u, v = np.arange(low[0], high[0] + 5, 5.0), np.arange(low[1], high[1] + 5, 5.0)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    backing = layout_to_part(
        assembly, np.stack([uu, vv], -1), np.full(uu.shape, -assembly.backing_depth_mm)
    )
    vertices.append(backing.reshape(-1, 3))
    backing_faces = _grid_faces(len(u), len(v), count)
    faces.append(backing_faces)
    owner.append(np.full(len(backing_faces), -1))
    mesh = Mesh("panel assembly", np.concatenate(vertices), np.concatenate(faces))
    return mesh, np.concatenate(owner)


def displacement_mm(panel: Panel, xs: np.ndarray) -> np.ndarray:
    """(N,) height change of the panel top at layout points (N, 2): dents < 0, bumps > 0."""
    height = np.zeros(len(xs))
    for dent in panel.dents:
        rho = np.linalg.norm(xs - dent.centre_mm, axis=1)
        bell = 0.5 * (1 + np.cos(np.pi * np.minimum(rho / dent.radius_mm, 1.0)))
        height -= dent.depth_mm * bell
    for scratch in panel.scratches:
        a, b = np.array(scratch.start_mm), np.array(scratch.end_mm)
        length = np.linalg.norm(b - a)
        direction = (b - a) / length
        t = (xs - a) @ direction
        u = (xs - a) @ np.array([-direction[1], direction[0]])
        section = np.clip(1 - (2 * u / scratch.width_mm) ** 2, 0.0, None)
        ends = np.clip(np.minimum(t, length - t) / scratch.width_mm, 0.0, 1.0)
        height -= scratch.depth_mm * section * ends
    return height


def lab_at(panel: Panel, xs: np.ndarray) -> np.ndarray:
    """(N, 3) L*a*b* of the panel top at layout points (N, 2), texture noise excluded."""
    lab = np.tile(np.array(panel.lab, dtype=np.float64), (len(xs), 1))
    for patch in panel.patches:
        angle = np.radians(patch.angle_deg)
        rotation = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
        local = (xs - patch.centre_mm) @ rotation.T / patch.semi_axes_mm
        rim = np.clip((1 - np.linalg.norm(local, axis=1)) / 0.15, 0.0, 1.0)
        lab += rim[:, None] * np.array(patch.delta_lab)
    return lab


# --- scanning ----------------------------------------------------------------------------


class AssemblyScanner:
    """The stitching simulator's sensor over an assembly, with its defects and colours."""

    def __init__(self, assembly: Assembly, base_T_part: np.ndarray, sensor: SensorModel) -> None:
        mesh, self.face_panel = assembly_mesh(assembly)
        self.assembly = assembly
        self.base_T_part = base_T_part
        self.part_T_base = invert(base_T_part)
        self.scanner = Scanner(mesh, base_T_part, sensor)
        self.panels = {p.id: p for p in assembly.panels}

    def scan(
        self, base_T_sensor: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """((rows, cols, 3) float32 sensor-frame grid with NaN holes, (rows, cols, 3) uint8
        sRGB)."""
        hits = self.scanner.cast(base_T_sensor)
        distance = hits.distance_mm.copy()
        points_base = base_T_sensor[:3, 3] + hits.directions_base * distance[:, None]
        hit = np.isfinite(distance)
        owner = np.full(len(distance), -1)
        owner[hit] = self.face_panel[hits.face[hit]]
        lab = np.tile(np.array(BACKING_LAB), (len(distance), 1))
        for panel_id in np.unique(owner[owner >= 0]):
            panel = self.panels[int(panel_id)]
            on = np.flatnonzero(owner == panel_id)
            layout, _ = part_to_layout(self.assembly, apply(self.part_T_base, points_base[on]))
            # A surface raised by δ along its normal meets the ray δ / cos(incidence) earlier.
            distance[on] -= displacement_mm(panel, layout) / hits.incidence_cos[on]
            lab[on] = lab_at(panel, layout)
        lab += rng.normal(0.0, self.assembly.texture_delta_e / np.sqrt(3), lab.shape)
        if self.assembly.dark_patches:
            distance = self._dark_patches(distance, points_base, rng)
        grid = self.scanner.measure(distance, rng)
        return grid, lab_to_srgb(lab).reshape(grid.shape)

    def _dark_patches(
        self, distance: np.ndarray, points_base: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """Holes and glints where the rays meet the dark patches."""
        hit = np.flatnonzero(np.isfinite(distance))
        layout, _ = part_to_layout(self.assembly, apply(self.part_T_base, points_base[hit]))
        out = distance.copy()
        for patch in self.assembly.dark_patches:
            inside = hit[np.linalg.norm(layout - patch.centre_mm, axis=1) < patch.radius_mm]
            draw = rng.random(len(inside))
            out[inside[draw < patch.hole_fraction]] = np.nan
            glint = inside[
                (draw >= patch.hole_fraction) & (draw < patch.hole_fraction + patch.spike_fraction)
            ]
            out[glint] += rng.uniform(0.5, 5.0, len(glint)) * rng.choice([-1.0, 1.0], len(glint))
        return out

    def edges_seen(self, poses: np.ndarray, seam: SeamTruth, fraction: np.ndarray) -> np.ndarray:
        """(K, 2) whether any of the views ``poses`` saw each side's edge where a gap is
        measured from, at ``fraction`` (K,) along the seam: a square edge's top and a
        chamfer's face ``EDGE_SEEN_MM`` from where its side face stands (its corner or
        foot: an edge placed by where its points stop), an arc a third of the way down
        (its shape places the rest). A side not seen there cannot be measured."""
        start, end = np.array(seam.start_mm), np.array(seam.end_mm)
        centre = start + np.asarray(fraction)[:, None] * (end - start)
        seen = np.zeros((len(centre), 2), bool)
        for side, panel_id in enumerate(seam.panels):
            panel = self.panels[panel_id]
            outline, inward = _closest_on_outline(panel.corners_mm, centre)
            edge = panel.edge
            inset = edge.size_mm / 2 if edge.kind == "round" else EDGE_SEEN_MM
            layout = outline + inset * inward
            height = panel.height_mm + edge.height_mm(np.full(len(layout), inset))
            points = apply(self.base_T_part, layout_to_part(self.assembly, layout, height))
            for pose in poses:
                seen[:, side] |= self.scanner.sees(pose, points)
        return seen


def _closest_on_outline(corners: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((N, 2) closest point on the polygon ``corners`` (counter-clockwise) to each of the
    layout points, (N, 2) the unit inward normal of the side it lies on)."""
    best = np.full(len(points), np.inf)
    closest, inward = np.zeros_like(points), np.zeros_like(points)
    for k in range(len(corners)):
        a, b = corners[k], corners[(k + 1) % len(corners)]
        direction = (b - a) / np.linalg.norm(b - a)
        along = np.clip((points - a) @ direction, 0.0, np.linalg.norm(b - a))
        foot = a + along[:, None] * direction
        distance = np.linalg.norm(points - foot, axis=1)
        nearer = distance < best
        best[nearer] = distance[nearer]
        closest[nearer] = foot[nearer]
        inward[nearer] = [-direction[1], direction[0]]
    return closest, inward


@dataclass(frozen=True)
class AssemblyScans:
    scans: list[np.ndarray]
    """(rows, cols, 3) float32 sensor-frame grids, NaN = no return."""
    colors: list[np.ndarray]
    """(rows, cols, 3) uint8 sRGB."""
    base_T_sensor: np.ndarray
    """(n, 4, 4) true sensor poses."""


def scan_assembly(
    assembly: Assembly,
    base_T_part: np.ndarray,
    sensor: SensorModel,
    *,
    overlap: float = 0.3,
    tilt_deg: float = 0.0,
    rng: np.random.Generator,
) -> AssemblyScans:
    """Snapshots over the assembly along the stitching workplan (true poses), each view
    tilted by ``tilt_deg`` about the base x axis through the point it looks at (seams
    running along x are then seen from the side: one side face in view, the other and
    part of the floor in shadow)."""
    from services.lib.pointcloud.scan_sim import workplan

    scanner = AssemblyScanner(assembly, base_T_part, sensor)
    base_T_sensor = workplan(scanner.scanner.mesh, base_T_part, sensor, overlap=overlap)
    if tilt_deg:
        base_T_sensor = np.stack([_tilted(p, tilt_deg, sensor.standoff_mm) for p in base_T_sensor])
    grids, colors = zip(*(scanner.scan(pose, rng) for pose in base_T_sensor), strict=True)
    return AssemblyScans(list(grids), list(colors), base_T_sensor)


def _tilted(base_T_sensor: np.ndarray, tilt_deg: float, standoff_mm: float) -> np.ndarray:
    """The view turned by ``tilt_deg`` about the base x axis through its aim point."""
    aim = base_T_sensor[:3, 3] + standoff_mm * base_T_sensor[:3, 2]
    angle = np.radians(tilt_deg)
    turn = np.array(
        [[1.0, 0.0, 0.0], [0.0, np.cos(angle), -np.sin(angle)], [0.0, np.sin(angle), np.cos(angle)]]
    )
    tilted = base_T_sensor.copy()
    tilted[:3, :3] = turn @ base_T_sensor[:3, :3]
    tilted[:3, 3] = aim + turn @ (base_T_sensor[:3, 3] - aim)
    return tilted
