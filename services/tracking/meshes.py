"""Triangle meshes of what a street holds, each triangle tagged with a material: cars of
four shapes (sedan, hatchback, SUV, van) lofted from longitudinal stations with a narrower
glass house, wheels; pedestrians, cyclists, poles, trees, bushes, walls.

A mesh is in its object's frame: origin at the centre of its bounding box's bottom face,
x forward, y left, z up, metres. ``Mesh.box_size`` is its bounding box (length, width,
height), which the simulator's labels use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# materials: (reflectance 0–1, probability that a return is lost, share of returns KITTI's
# Velodyne reports at reflectance 0). Read off KITTI's scans: car paint is dark (over half
# its returns at 0), the road about 0.27, walls and plants 0.2–0.3 with many zeros.
MATERIALS = {
    "paint": (0.12, 0.04, 0.55),
    "glass": (0.05, 0.75, 0.60),
    "tyre": (0.05, 0.10, 0.50),
    "light": (0.55, 0.02, 0.30),
    "road": (0.30, 0.02, 0.07),
    "marking": (0.70, 0.01, 0.0),
    "kerb": (0.32, 0.02, 0.05),
    "sidewalk": (0.33, 0.02, 0.05),
    "terrain": (0.30, 0.05, 0.10),
    "wall": (0.32, 0.02, 0.20),
    "metal": (0.45, 0.03, 0.25),
    "bark": (0.25, 0.05, 0.30),
    "foliage": (0.35, 0.35, 0.30),
    "cloth": (0.25, 0.05, 0.30),
    "skin": (0.30, 0.05, 0.20),
}
MATERIAL_NAMES = tuple(MATERIALS)
REFLECTANCE = np.array([MATERIALS[name][0] for name in MATERIAL_NAMES])
DROPOUT = np.array([MATERIALS[name][1] for name in MATERIAL_NAMES])
DARK = np.array([MATERIALS[name][2] for name in MATERIAL_NAMES])
CAR_SHAPES = ("sedan", "hatchback", "suv", "van")


def material(name: str) -> int:
    return MATERIAL_NAMES.index(name)


@dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray
    """(V, 3) float64, metres, the object's frame."""
    triangles: np.ndarray
    """(T, 3) int32 vertex indices, counter-clockwise seen from outside."""
    materials: np.ndarray
    """(T,) int material index into ``MATERIAL_NAMES``."""

    @property
    def box_size(self) -> np.ndarray:
        """(length, width, height) of the bounding box, metres."""
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)

    def placed(self, world_T_object: np.ndarray) -> Mesh:
        vertices = self.vertices @ world_T_object[:3, :3].T + world_T_object[:3, 3]
        return Mesh(vertices, self.triangles, self.materials)


def merge(*meshes: Mesh) -> Mesh:
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return Mesh(
        np.concatenate([m.vertices for m in meshes]),
        np.concatenate([m.triangles + o for m, o in zip(meshes, offsets, strict=True)]).astype(
            np.int32
        ),
        np.concatenate([m.materials for m in meshes]),
    )


def _ring_mesh(sections: np.ndarray, section_materials: np.ndarray, cap: str | np.ndarray) -> Mesh:
    """A closed tube through ``sections`` (S, K, 3): S rings of K vertices each, joined by
    quads (band s–s+1, edge k–k+1 takes ``section_materials[s, k]``) and capped at both ends
    by fans (material ``cap``, or (K,) materials of the fan's triangles: edge k–k+1)."""
    count, ring = sections.shape[:2]
    index = np.arange(count * ring).reshape(count, ring)
    a, b = index[:-1], np.roll(index[:-1], -1, axis=1)
    c, d = index[1:], np.roll(index[1:], -1, axis=1)
    quads = np.concatenate(
        [np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)]
    )
    quad_materials = np.concatenate([section_materials.ravel(), section_materials.ravel()])
    first_centre, last_centre = count * ring, count * ring + 1
    fan = np.arange(ring)
    caps = np.concatenate(
        [
            np.column_stack(
                [np.full(ring, first_centre), index[0, np.roll(fan, -1)], index[0, fan]]
            ),
            np.column_stack(
                [np.full(ring, last_centre), index[-1, fan], index[-1, np.roll(fan, -1)]]
            ),
        ]
    )
    vertices = np.concatenate(
        [
            sections.reshape(-1, 3),
            sections[0].mean(axis=0, keepdims=True),
            sections[-1].mean(axis=0, keepdims=True),
        ]
    )
    fan_materials = np.full(ring, material(cap)) if isinstance(cap, str) else np.asarray(cap)
    materials = np.concatenate([quad_materials, fan_materials, fan_materials])
    return Mesh(vertices, np.concatenate([quads, caps]).astype(np.int32), materials)


def cylinder(radius_m: float, height_m: float, kind: str, segments: int = 12) -> Mesh:
    """An upright cylinder standing on z = 0, centred on the z axis."""
    angle = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.column_stack([radius_m * np.cos(angle), radius_m * np.sin(angle)])
    sections = np.stack([np.column_stack([ring, np.full(segments, z)]) for z in (0.0, height_m)])
    return _ring_mesh(sections, np.full((1, segments), material(kind)), kind)


def box(length_m: float, width_m: float, height_m: float, kind: str) -> Mesh:
    """A box standing on z = 0, centred on the z axis, length along x."""
    x, y = length_m / 2, width_m / 2
    ring = np.array([[x, y, 0], [-x, y, 0], [-x, -y, 0], [x, -y, 0]], dtype=np.float64)
    sections = np.stack([ring, ring + [0, 0, height_m]])
    return _ring_mesh(sections, np.full((1, 4), material(kind)), kind)


def blob(radius_m: float, rng: np.random.Generator, kind: str, bumps: float = 0.25) -> Mesh:
    """A lumpy ball (a bush or a tree's crown) resting on z = 0."""
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=8)
    vertices = np.asarray(sphere.vertices)
    triangles = np.asarray(sphere.triangles).astype(np.int32)
    waves = rng.normal(size=(4, 3))
    phases = rng.uniform(0, 2 * np.pi, 4)
    relief = np.sin(vertices @ waves.T * 2.0 + phases).mean(axis=1)
    vertices = vertices * radius_m * (1 + bumps * relief)[:, None]
    vertices[:, 2] -= vertices[:, 2].min()
    return Mesh(vertices, triangles, np.full(len(triangles), material(kind)))


def _wheel(radius_m: float, width_m: float) -> Mesh:
    """A wheel lying along y (its axle), centred at the origin."""
    mesh = cylinder(radius_m, width_m, "tyre", segments=10)
    rotate = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # z → y
    vertices = (mesh.vertices - [0, 0, width_m / 2]) @ rotate.T
    return Mesh(vertices, mesh.triangles, mesh.materials)


# Each shape: stations along the length (0 = rear, 1 = front) with the body's top (share of
# the height) and whether the glass house stands there.
SHAPE_PROFILES = {
    "sedan": {
        "station": [0.0, 0.04, 0.22, 0.30, 0.42, 0.66, 0.80, 0.96, 1.0],
        "top": [0.50, 0.62, 0.66, 0.70, 1.0, 1.0, 0.70, 0.60, 0.48],
        "glass": [0, 0, 0, 0, 1, 1, 0, 0, 0],
    },
    "hatchback": {
        "station": [0.0, 0.03, 0.08, 0.20, 0.62, 0.76, 0.95, 1.0],
        "top": [0.55, 0.66, 0.93, 1.0, 1.0, 0.70, 0.62, 0.50],
        "glass": [0, 0, 1, 1, 1, 0, 0, 0],
    },
    "suv": {
        "station": [0.0, 0.03, 0.06, 0.16, 0.70, 0.80, 0.96, 1.0],
        "top": [0.55, 0.68, 0.96, 1.0, 1.0, 0.72, 0.66, 0.55],
        "glass": [0, 0, 1, 1, 1, 0, 0, 0],
    },
    "van": {
        "station": [0.0, 0.02, 0.06, 0.78, 0.88, 0.97, 1.0],
        "top": [0.70, 0.98, 1.0, 1.0, 0.70, 0.60, 0.52],
        "glass": [0, 0, 0, 1, 0, 0, 0],
    },
}
SHAPE_SIZES_M = {
    # (length, width, height) ranges: KITTI's cars are small European ones (mean 3.9 × 1.6 × 1.5)
    "sedan": ((4.1, 4.8), (1.65, 1.82), (1.38, 1.52)),
    "hatchback": ((3.4, 4.1), (1.55, 1.75), (1.40, 1.56)),
    "suv": ((4.2, 4.8), (1.75, 1.92), (1.58, 1.80)),
    "van": ((4.5, 5.4), (1.85, 2.02), (1.85, 2.25)),
}


def car(shape: str, length_m: float, width_m: float, height_m: float) -> Mesh:
    """A car body lofted through its shape's stations: a lower body the full width from the
    sills to the shoulder, a glass house above it pulled in by a tumblehome, wheels."""
    profile = SHAPE_PROFILES[shape]
    station = np.asarray(profile["station"])
    top_share = np.asarray(profile["top"])
    glass_at = np.asarray(profile["glass"], bool)
    wheel_radius = np.clip(0.21 * height_m, 0.28, 0.40)
    sill = 0.55 * wheel_radius
    shoulder = np.minimum(0.62 * height_m, top_share * height_m)
    top = top_share * height_m
    half_width = width_m / 2 * np.where((station < 0.02) | (station > 0.98), 0.92, 1.0)
    roof_half = np.where(glass_at, 0.74, 0.92) * half_width
    x = (station - 0.5) * length_m
    # a cross-section of 10 vertices, left sill round to the right sill
    ys = np.stack(
        [-0.92 * half_width, -half_width, -half_width, -roof_half, -0.8 * roof_half,
         0.8 * roof_half, roof_half, half_width, half_width, 0.92 * half_width], axis=1,
    )  # fmt: skip
    zs = np.stack(
        [np.full_like(x, sill), sill + 0.2 * (shoulder - sill), shoulder,
         top - 0.04 * height_m * glass_at, top, top, top - 0.04 * height_m * glass_at,
         shoulder, sill + 0.2 * (shoulder - sill), np.full_like(x, sill)], axis=1,
    )  # fmt: skip
    sections = np.stack([np.broadcast_to(x[:, None], ys.shape), ys, zs], axis=-1)
    kinds = np.full((len(x) - 1, 10), material("paint"))
    glass_band = glass_at[:-1] | glass_at[1:]
    kinds[glass_band, 2] = material("glass")  # the left side windows, shoulder to roof
    kinds[glass_band, 6] = material("glass")  # the right ones
    sloped = (np.diff(top) < -0.05 * height_m) | (np.diff(top) > 0.05 * height_m)
    kinds[sloped & glass_band, 3:6] = material("glass")  # windscreen and rear window
    # the ends painted, with lamps at the shoulders' corners
    ends = np.full(10, material("paint"))
    ends[[1, 7]] = material("light")
    body = _ring_mesh(sections, kinds, ends)
    wheel_x = (np.array([0.18, 0.82]) - 0.5) * length_m
    wheels = [
        _wheel(wheel_radius, 0.2).placed(
            _translation(wx, side * (width_m / 2 - 0.12), wheel_radius)
        )
        for wx in wheel_x
        for side in (-1, 1)
    ]
    mesh = merge(body, *wheels)
    return _centred(mesh)


def _translation(x: float, y: float, z: float) -> np.ndarray:
    out = np.eye(4)
    out[:3, 3] = (x, y, z)
    return out


def _centred(mesh: Mesh) -> Mesh:
    """The mesh moved so its bounding box's bottom face is centred on the origin."""
    low, high = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    shift = np.array([(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, low[2]])
    return Mesh(mesh.vertices - shift, mesh.triangles, mesh.materials)


def random_car(rng: np.random.Generator, shape: str | None = None) -> tuple[str, Mesh]:
    shape = shape or str(rng.choice(CAR_SHAPES, p=[0.38, 0.32, 0.18, 0.12]))
    (l0, l1), (w0, w1), (h0, h1) = SHAPE_SIZES_M[shape]
    return shape, car(shape, rng.uniform(l0, l1), rng.uniform(w0, w1), rng.uniform(h0, h1))


def truck(rng: np.random.Generator) -> Mesh:
    """A lorry (KITTI's Truck): a cab and a cargo box on six wheels, 6.5–10 m long."""
    length, width = rng.uniform(6.5, 10.0), rng.uniform(2.3, 2.55)
    cab_length, height = 2.2, rng.uniform(2.9, 3.7)
    wheel = 0.5
    cargo = box(length - cab_length - 0.3, width, height - 0.9, "paint").placed(
        _translation(-(cab_length + 0.3) / 2, 0, 0.9)
    )
    cab = box(cab_length, width, 2.1, "paint").placed(
        _translation((length - cab_length) / 2, 0, 0.8)
    )
    screen = box(0.05, width * 0.8, 0.8, "glass").placed(_translation(length / 2, 0, 1.9))
    wheels = [
        _wheel(wheel, 0.3).placed(_translation(x * length, side * (width / 2 - 0.2), wheel))
        for x in (-0.35, -0.2, 0.38)
        for side in (-1, 1)
    ]
    return _centred(merge(cargo, cab, screen, *wheels))


def pedestrian(rng: np.random.Generator) -> Mesh:
    """Legs, a torso, arms and a head: 1.55–1.95 m tall, facing x."""
    height = rng.uniform(1.55, 1.95)
    leg = 0.47 * height
    legs = [
        box(0.16, 0.14, leg, "cloth").placed(_translation(0.0, side * 0.1, 0.0)) for side in (-1, 1)
    ]
    torso = box(0.24, 0.42, 0.33 * height, "cloth").placed(_translation(0, 0, leg))
    arms = [
        box(0.1, 0.09, 0.3 * height, "cloth").placed(
            _translation(0, side * 0.26, leg + 0.02 * height)
        )
        for side in (-1, 1)
    ]
    head = box(0.2, 0.17, height - leg - 0.33 * height, "skin").placed(
        _translation(0, 0, leg + 0.33 * height)
    )
    return _centred(merge(*legs, torso, *arms, head))


def cyclist(rng: np.random.Generator) -> Mesh:
    """A bicycle (two thin wheels and a frame) with its rider, facing x: about 1.8 m long."""
    wheel_radius = 0.34
    wheels = [
        cylinder(wheel_radius, 0.05, "tyre", 12)
        .placed(np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0.025], [0, 1.0, 0, 0], [0, 0, 0, 1]]))
        .placed(_translation(x, 0.0, wheel_radius))
        for x in (-0.55, 0.55)
    ]
    frame = box(1.0, 0.06, 0.1, "metal").placed(_translation(0, 0, 0.55))
    rider = pedestrian(rng)
    scale = np.diag([1.0, 1.0, 0.8])  # seated
    seated = Mesh(rider.vertices @ scale.T + [-0.1, 0, 0.55], rider.triangles, rider.materials)
    return _centred(merge(*wheels, frame, seated))


def shrub(rng: np.random.Generator) -> Mesh:
    """Two to five lumps of foliage grown together, 0.5–3.5 m across."""
    lumps = []
    for _ in range(int(rng.integers(2, 6))):
        lump = blob(rng.uniform(0.3, 1.1), rng, "foliage", 0.35)
        shift = _translation(rng.uniform(-1.0, 1.0), rng.uniform(-0.8, 0.8), rng.uniform(-0.2, 0.4))
        lumps.append(lump.placed(shift))
    mesh = merge(*lumps)
    vertices = mesh.vertices.copy()
    vertices[:, 2] = np.maximum(vertices[:, 2], 0.0)
    return _centred(Mesh(vertices, mesh.triangles, mesh.materials))


def tree(rng: np.random.Generator) -> Mesh:
    trunk_height = rng.uniform(1.2, 3.5)
    crown = rng.uniform(1.0, 3.2)
    return merge(
        cylinder(rng.uniform(0.1, 0.25), trunk_height + crown * 0.5, "bark", 8),
        blob(crown, rng, "foliage").placed(_translation(0, 0, trunk_height)),
    )
