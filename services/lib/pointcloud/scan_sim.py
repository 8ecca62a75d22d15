"""Simulated scanning: component meshes, a workplan, a snapshot sensor, robot pose noise.

The sensor is a pinhole snapshot device like the LMI Gocator 3210: rays from its origin
through a grid covering ``field_mm`` at ``standoff_mm``; a ray returns where it first hits
the mesh (occlusion included), inside the measuring range and not too grazing, with
Gaussian noise along the ray. The result is an organized grid in the sensor frame, NaN
where nothing was measured. Frames: {B} base, {F} flange, {G} sensor, {P} part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.lib.pointcloud.transforms import invert, look_at, make_transform, perturb

GOCATOR_GRID = (1288, 1936)
"""(rows, columns): about 2.5 M points over 100 × 154 mm, the Gocator 3210's snapshot."""


@dataclass(frozen=True)
class Mesh:
    """vertices : (V, 3) float64, mm, part frame; faces : (F, 3) int (counter-clockwise
    seen from the side a sensor scans)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class SensorModel:
    grid: tuple[int, int] = (100, 154)
    """(rows, columns) of the organized scan."""
    field_mm: tuple[float, float] = (154.0, 100.0)
    """(width, height) of the field at the standoff."""
    standoff_mm: float = 220.0
    range_mm: float = 110.0
    """Measuring range centred on the standoff; hits outside it are not returned."""
    noise_mm: float = 0.02
    """1σ along the ray."""
    max_incidence_deg: float = 75.0
    """Steeper surfaces return nothing (a snapshot sensor's dropout)."""
    outlier_fraction: float = 0.002
    outlier_mm: tuple[float, float] = (0.5, 5.0)
    """Stray returns (multipath, specular glints): that share of pixels off along the ray by
    a random distance in this range, either way."""
    mixed_pixel_fraction: float = 0.0
    """Share of the pixels at a depth jump (a neighbour's return more than ``jump_mm``
    nearer or farther: an edge over a gap) that return a mix of the two surfaces — a point
    anywhere between them along the ray (the footprint straddles the edge)."""
    edge_spike_fraction: float = 0.0
    """Share of the pixels at a depth jump that return a spike (off along the ray by a
    distance in ``outlier_mm``, either way)."""
    jump_mm: float = 1.0


@dataclass(frozen=True)
class ScanSession:
    """What a robot recorded while scanning, and the truth."""

    scans: list[np.ndarray]
    """(rows, columns, 3) float32 grids in the sensor frame, mm; NaN = not measured."""
    base_T_flange: np.ndarray
    """(n, 4, 4) as reported by the robot (with its repeatability error)."""
    true_base_T_flange: np.ndarray
    base_T_part: np.ndarray
    mesh: Mesh


def _grid_surface(name: str, u: np.ndarray, v: np.ndarray, surface) -> Mesh:  # noqa: ANN001
    """Triangulate ``surface(U, V) → (…, 3)`` over the grid u × v."""
    uu, vv = np.meshgrid(u, v, indexing="ij")
    vertices = surface(uu, vv).reshape(-1, 3)
    rows, cols = len(u), len(v)
    index = np.arange(rows * cols).reshape(rows, cols)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return Mesh(name, vertices, faces)


def flat_panel(length_mm: float = 300.0, width_mm: float = 200.0) -> Mesh:
    return _grid_surface(
        "flat panel",
        np.linspace(0, length_mm, 2),
        np.linspace(0, width_mm, 2),
        lambda x, y: np.stack([x, y, np.zeros_like(x)], -1),
    )


def curved_panel(
    length_mm: float = 300.0, width_mm: float = 200.0, radius_mm: float = 1500.0
) -> Mesh:
    """A sidewall-like panel bent about the x axis with ``radius_mm``."""

    def surface(x: np.ndarray, s: np.ndarray) -> np.ndarray:
        angle = (s - width_mm / 2) / radius_mm
        return np.stack([x, radius_mm * np.sin(angle), radius_mm * (np.cos(angle) - 1)], -1)

    return _grid_surface(
        "curved panel", np.linspace(0, length_mm, 2), np.linspace(0, width_mm, 121), surface
    )


def angle_profile(length_mm: float = 300.0, leg_mm: float = 60.0, fillet_mm: float = 5.0) -> Mesh:
    """A carbon angle profile, length along x: two legs at 90° joined by an inner fillet,
    lying as a V (each leg 45° from the horizontal) so a sensor above sees both faces."""
    theta = np.linspace(0, np.pi / 2, 16)
    arc = fillet_mm + fillet_mm * np.stack([-np.sin(theta), -np.cos(theta)], 1)
    section = np.concatenate([[[leg_mm, 0.0]], arc, [[0.0, leg_mm]]])  # (y, z) of the L
    c = np.cos(np.pi / 4)
    v_shape = section @ np.array([[c, c], [-c, c]])  # legs rise at ±45°

    def surface(x: np.ndarray, i: np.ndarray) -> np.ndarray:
        j = i.astype(int)
        return np.stack([x, v_shape[j, 0], v_shape[j, 1]], -1)

    return _grid_surface(
        "angle profile", np.linspace(0, length_mm, 2), np.arange(len(section)), surface
    )


def flat_strip() -> Mesh:
    """A flat strip that ten Gocator fields (5 × 2, 30 % overlap) tile edge to edge, so
    every snapshot sees the part with all its ~2.5 M pixels: 585 × 169.8 mm."""
    return flat_panel(585.0, 169.8)


COMPONENTS = {
    "angle": angle_profile,
    "flat": flat_panel,
    "curved": curved_panel,
    "strip": flat_strip,
}
"""The simulated parts by their short name (``vista simulate stitching --component``)."""


def workplan(
    mesh: Mesh, base_T_part: np.ndarray, sensor: SensorModel, *, overlap: float = 0.3
) -> np.ndarray:
    """(n, 4, 4) base_T_sensor looking straight down (−z of the base) over the part's
    footprint in a boustrophedon, neighbouring fields overlapping by ``overlap``."""
    corners = mesh.vertices @ base_T_part[:3, :3].T + base_T_part[:3, 3]
    low, high = corners.min(0), corners.max(0)
    step = np.array(sensor.field_mm) * (1 - overlap)
    counts = np.maximum(1, np.ceil((high[:2] - low[:2] - sensor.field_mm) / step).astype(int) + 1)
    spans = (counts - 1) * step
    centre = (low[:2] + high[:2]) / 2
    xs = centre[0] - spans[0] / 2 + step[0] * np.arange(counts[0])
    ys = centre[1] - spans[1] / 2 + step[1] * np.arange(counts[1])
    poses = []
    for row, y in enumerate(ys):
        for x in xs if row % 2 == 0 else xs[::-1]:
            eye = np.array([x, y, high[2] + sensor.standoff_mm])
            poses.append(look_at(eye, eye - [0, 0, 1], np.array([0.0, -1.0, 0.0])))
    return np.stack(poses)


def _rays(sensor: SensorModel) -> np.ndarray:
    """(rows, columns, 3) unit ray directions in the sensor frame (+z forward)."""
    rows, cols = sensor.grid
    width, height = sensor.field_mm
    x = np.linspace(-width / 2, width / 2, cols) / sensor.standoff_mm
    y = np.linspace(-height / 2, height / 2, rows) / sensor.standoff_mm
    xx, yy = np.meshgrid(x, y)
    directions = np.stack([xx, yy, np.ones_like(xx)], -1)
    return directions / np.linalg.norm(directions, axis=-1, keepdims=True)


@dataclass(frozen=True)
class Hits:
    """One snapshot's rays against the mesh, flattened over the sensor grid (P pixels)."""

    distance_mm: np.ndarray
    """(P,) along the ray to the first hit; NaN where the sensor returns nothing (no hit,
    out of range, too grazing)."""
    incidence_cos: np.ndarray
    """(P,) |cos| of the angle between the ray and the hit face's normal."""
    face: np.ndarray
    """(P,) int64 index of the hit face, −1 where nothing is returned."""
    directions_base: np.ndarray
    """(P, 3) unit ray directions in the base frame."""


class Scanner:
    """Casts the sensor's rays at a mesh placed in the base frame."""

    def __init__(self, mesh: Mesh, base_T_part: np.ndarray, sensor: SensorModel) -> None:
        import open3d as o3d

        self.sensor = sensor
        self.mesh = mesh
        vertices = (mesh.vertices @ base_T_part[:3, :3].T + base_T_part[:3, 3]).astype(np.float32)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(vertices), o3d.core.Tensor(mesh.faces.astype(np.uint32))
        )
        self.directions = _rays(sensor)

    def cast(self, base_T_sensor: np.ndarray) -> Hits:
        """Where each pixel's ray first meets the mesh, before noise."""
        import open3d as o3d

        directions_base = self.directions.reshape(-1, 3) @ base_T_sensor[:3, :3].T
        origins = np.broadcast_to(base_T_sensor[:3, 3], directions_base.shape)
        rays = np.hstack([origins, directions_base]).astype(np.float32)
        hits = self.scene.cast_rays(o3d.core.Tensor(rays))
        distance = hits["t_hit"].numpy().astype(np.float64)
        normals = hits["primitive_normals"].numpy()
        incidence = np.abs(np.sum(normals * directions_base, axis=1))
        depth = distance * self.directions.reshape(-1, 3)[:, 2]
        measured = np.isfinite(distance) & self._returns(depth, incidence)
        face = np.where(measured, hits["primitive_ids"].numpy().astype(np.int64), -1)
        return Hits(np.where(measured, distance, np.nan), incidence, face, directions_base)

    def _returns(self, depth_mm: np.ndarray, incidence_cos: np.ndarray) -> np.ndarray:
        """Whether hits at these depths and incidences are returned (in range, not too
        grazing)."""
        sensor = self.sensor
        return (np.abs(depth_mm - sensor.standoff_mm) <= sensor.range_mm / 2) & (
            incidence_cos >= np.cos(np.radians(sensor.max_incidence_deg))
        )

    def sees(
        self, base_T_sensor: np.ndarray, points_base: np.ndarray, tolerance_mm: float = 0.01
    ) -> np.ndarray:
        """(P,) whether the sensor at this pose returns each of the points on the mesh:
        inside its field and range, the first hit along its ray (nothing in front of it
        by more than ``tolerance_mm``), not too grazing."""
        import open3d as o3d

        sensor = self.sensor
        origin = base_T_sensor[:3, 3]
        offset = points_base - origin
        distance = np.linalg.norm(offset, axis=1)
        directions_base = offset / distance[:, None]
        local = directions_base @ base_T_sensor[:3, :3]  # in the sensor frame
        half_width, half_height = np.array(sensor.field_mm) / 2 / sensor.standoff_mm
        forward = np.maximum(local[:, 2], 1e-12)
        inside = (
            (local[:, 2] > 0)
            & (np.abs(local[:, 0]) <= half_width * forward)
            & (np.abs(local[:, 1]) <= half_height * forward)
        )
        rays = np.hstack([np.broadcast_to(origin, offset.shape), directions_base])
        hits = self.scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
        first = hits["t_hit"].numpy().astype(np.float64)
        incidence = np.abs(np.sum(hits["primitive_normals"].numpy() * directions_base, axis=1))
        unblocked = first >= distance - tolerance_mm
        return inside & unblocked & self._returns(distance * local[:, 2], incidence)

    def measure(self, distance_mm: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The organized grid the sensor reports for true ray distances (noise, strays):
        (rows, columns, 3) float32 in the sensor frame; NaN = no return."""
        sensor = self.sensor
        distance = distance_mm + rng.normal(0.0, sensor.noise_mm, distance_mm.shape)
        stray = rng.random(distance.shape) < sensor.outlier_fraction
        if sensor.mixed_pixel_fraction or sensor.edge_spike_fraction:
            distance = _edge_artefacts(distance, distance_mm.reshape(sensor.grid), sensor, rng)
        distance[stray] += rng.uniform(*sensor.outlier_mm, stray.sum()) * rng.choice(
            [-1.0, 1.0], stray.sum()
        )
        points = self.directions.reshape(-1, 3) * distance[:, None]
        return points.reshape(*sensor.grid, 3).astype(np.float32)

    def scan(self, base_T_sensor: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(rows, columns, 3) float32 organized grid in the sensor frame; NaN = no return."""
        return self.measure(self.cast(base_T_sensor).distance_mm, rng)

    def distance_to_surface_mm(self, points_base: np.ndarray) -> np.ndarray:
        """Unsigned distance of (N, 3) base-frame points to the mesh, mm."""
        import open3d as o3d

        query = o3d.core.Tensor(np.ascontiguousarray(points_base, dtype=np.float32))
        return self.scene.compute_distance(query).numpy()


def _edge_artefacts(
    distance: np.ndarray, true_grid: np.ndarray, sensor: SensorModel, rng: np.random.Generator
) -> np.ndarray:
    """Mixed pixels and spikes where the true depth jumps between neighbouring pixels."""
    farther = np.full(true_grid.shape, np.nan)  # the other surface of the jump, if any
    for axis in (0, 1):
        for shift in (1, -1):
            neighbour = np.roll(true_grid, shift, axis)
            edge = [slice(None), slice(None)]
            edge[axis] = 0 if shift == 1 else -1
            neighbour[tuple(edge)] = np.nan
            jump = np.abs(neighbour - true_grid) > sensor.jump_mm
            farther = np.where(jump & ~np.isfinite(farther), neighbour, farther)
    at_jump = np.isfinite(farther).ravel() & np.isfinite(distance)
    draw = rng.random(distance.shape)
    mixed = at_jump & (draw < sensor.mixed_pixel_fraction)
    spike = at_jump & ~mixed & (draw < sensor.mixed_pixel_fraction + sensor.edge_spike_fraction)
    out = distance.copy()
    other = farther.ravel()
    out[mixed] += rng.uniform(0.0, 1.0, mixed.sum()) * (other[mixed] - distance[mixed])
    out[spike] += rng.uniform(*sensor.outlier_mm, spike.sum()) * rng.choice(
        [-1.0, 1.0], spike.sum()
    )
    return out


def simulate_scans(
    mesh: Mesh,
    flange_T_sensor: np.ndarray,
    *,
    sensor: SensorModel | None = None,
    robot_sigma_mm: float,
    robot_sigma_deg: float,
    overlap: float = 0.3,
    rng: np.random.Generator,
) -> ScanSession:
    """Scan ``mesh`` (placed in front of the robot) along a workplan; report poses with the
    robot's noise (1σ per axis; the caller's robot: a library states none of its own)."""
    sensor = sensor or SensorModel()
    base_T_part = make_transform(np.eye(3), np.array([550.0, -100.0, -250.0]))
    base_T_sensor = workplan(mesh, base_T_part, sensor, overlap=overlap)
    true_base_T_flange = base_T_sensor @ invert(flange_T_sensor)
    reported = perturb(true_base_T_flange, robot_sigma_mm, robot_sigma_deg, rng)
    scanner = Scanner(mesh, base_T_part, sensor)
    scans = [scanner.scan(pose, rng) for pose in base_T_sensor]
    return ScanSession(scans, reported, true_base_T_flange, base_T_part, mesh)
