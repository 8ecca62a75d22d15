"""A spinning 64-beam LiDAR with the Velodyne HDL-64E's geometry as KITTI mounted it:
64 rings from +2° to −24.9° (the upper block every ⅓°, the lower every ½°), 2 048 firings
a turn at 10 Hz, 1.73 m above the road.

The sensor turns while the car moves, as KITTI's raw scans do (not motion-compensated): a
firing's time is its azimuth's share of the turn around the frame's time (the camera's
trigger, when the beams face forward), and every point is given in the sensor's frame at
its own firing. A moving object is cast in its own frame with its pose at each firing. A return is kept with its material's and the range's odds (glass and foliage drop
most, far and grazing returns fade); its range is noisy, its reflectance falls a little with
the angle of incidence, and dark surfaces (car paint) often read 0, as KITTI's do.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from services.tracking.meshes import DARK, DROPOUT, REFLECTANCE, Mesh

UPPER_DEG = np.linspace(2.0, -8.33, 32)
LOWER_DEG = np.linspace(-8.83, -24.9, 32)
ELEVATIONS_DEG = np.concatenate([UPPER_DEG, LOWER_DEG])
COLUMNS = 2048
SCAN_PERIOD_S = 0.1
MOUNT_HEIGHT_M = 1.73


@dataclass(frozen=True)
class LidarModel:
    elevations_deg: tuple[float, ...] = tuple(ELEVATIONS_DEG)
    columns: int = COLUMNS
    min_range_m: float = 2.5
    max_range_m: float = 110.0
    range_noise_m: float = 0.02
    base_dropout: float = 0.03
    period_s: float = SCAN_PERIOD_S

    @property
    def rays(self) -> int:
        return len(self.elevations_deg) * self.columns

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, 3) unit directions in the sensor frame, ring-major (ring 0 = the highest),
        and (R,) each firing's time offset from the frame's, seconds: the turn starts
        behind the car and passes forward (azimuth 0) at offset 0."""
        column = np.arange(self.columns)
        azimuth = np.pi - 2 * np.pi * (column + 0.5) / self.columns
        elevation = np.radians(np.asarray(self.elevations_deg))
        ce, se = np.cos(elevation)[:, None], np.sin(elevation)[:, None]
        directions = np.stack(
            [
                ce * np.cos(azimuth),
                ce * np.sin(azimuth),
                np.broadcast_to(se, (len(elevation), self.columns)),
            ],
            axis=-1,
        ).reshape(-1, 3)
        offset = ((column + 0.5) / self.columns - 0.5) * self.period_s
        return directions, np.tile(offset, len(elevation))


@dataclass(frozen=True)
class Scan:
    points: np.ndarray
    """(N, 4) float32 ``x y z reflectance``, metres, each point in the sensor's frame at its
    firing."""
    hit_object: np.ndarray
    """(N,) the object each point hit (index into the frame's objects), −1 for the static
    world that no label names."""
    ray: np.ndarray
    """(N,) the index of each point's firing (ring × columns + column)."""


class StaticWorld:
    """The street's fixed meshes in one ray-casting scene (built once)."""

    def __init__(self, meshes: list[Mesh], objects: list[int]) -> None:
        """``objects[i]``: the labelled object mesh ``i`` is (−1: none)."""
        import open3d as o3d

        self.scene = o3d.t.geometry.RaycastingScene()
        self.materials = []
        self.object_of_geometry = []
        for mesh, obj in zip(meshes, objects, strict=True):
            self.scene.add_triangles(
                o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                o3d.core.Tensor(mesh.triangles.astype(np.uint32)),
            )
            self.materials.append(mesh.materials)
            self.object_of_geometry.append(obj)
        self.object_of_geometry = np.asarray(self.object_of_geometry)


def _cast(scene, origins: np.ndarray, directions: np.ndarray, threads: int) -> dict:  # noqa: ANN001 - an open3d scene
    import open3d as o3d

    rays = np.concatenate([origins, directions], axis=1).astype(np.float32)
    hits = scene.cast_rays(o3d.core.Tensor(rays), nthreads=threads)
    return {
        key: hits[key].numpy()
        for key in ("t_hit", "geometry_ids", "primitive_ids", "primitive_normals")
    }


class Mover:
    """A moving object's mesh in its own frame, in a ray-casting scene of its own (built
    once): each firing is cast in the object's frame at the firing's time."""

    def __init__(self, index: int, mesh: Mesh) -> None:
        import open3d as o3d

        self.index = index
        self.materials = mesh.materials
        self.radius_m = float(
            np.linalg.norm(mesh.vertices - mesh.vertices.mean(axis=0), axis=1).max()
        )
        self.centre = mesh.vertices.mean(axis=0)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(mesh.vertices.astype(np.float32)),
            o3d.core.Tensor(mesh.triangles.astype(np.uint32)),
        )


def _window_columns(model: LidarModel, centre_sensor: np.ndarray, radius_m: float) -> np.ndarray:
    """The columns whose beams may meet an object of ``radius_m`` around ``centre_sensor``
    (the sensor's frame), with room for its motion during the turn."""
    distance = float(np.hypot(centre_sensor[0], centre_sensor[1]))
    if distance <= radius_m + 3.0:
        return np.arange(model.columns)
    azimuth = np.arctan2(centre_sensor[1], centre_sensor[0])
    half = np.arcsin(min(1.0, (radius_m + 3.0) / distance))
    first = (np.pi - (azimuth + half)) / (2 * np.pi) * model.columns - 0.5
    last = (np.pi - (azimuth - half)) / (2 * np.pi) * model.columns - 0.5
    return np.arange(int(np.floor(first)), int(np.ceil(last)) + 1) % model.columns


def scan(
    model: LidarModel,
    world: StaticWorld,
    world_T_sensor: Callable[[np.ndarray], np.ndarray],
    moving: list[tuple[Mover, Callable[[np.ndarray], np.ndarray]]],
    rng: np.random.Generator,
    *,
    threads: int = 2,
) -> Scan:
    """One turn of the sensor. ``world_T_sensor(offsets_s)`` gives (K, 4, 4) poses at time
    offsets from the frame's; ``moving`` the moving objects with a function giving their
    ``world_T_object`` (K, 4, 4) at time offsets."""
    import open3d as o3d

    local, offset = model.directions()
    columns = model.columns
    poses = world_T_sensor(offset[:columns])  # a firing's pose depends on its column only
    column = np.arange(model.rays) % columns
    origins = poses[column, :3, 3]
    directions = np.einsum("rij,rj->ri", poses[column, :3, :3], local)
    static = _cast(world.scene, origins, directions, threads)
    t_hit = static["t_hit"].astype(np.float64)
    hit_geometry = static["geometry_ids"].astype(np.int64)
    invalid = np.uint32(o3d.t.geometry.RaycastingScene.INVALID_ID)
    hit_static = hit_geometry != invalid
    material = np.full(model.rays, -1)
    obj = np.full(model.rays, -1)
    rows = np.flatnonzero(hit_static)
    geometry = hit_geometry[rows]
    material[rows] = _materials(world.materials, geometry, static["primitive_ids"][rows])
    obj[rows] = world.object_of_geometry[geometry]
    normals = static["primitive_normals"].astype(np.float64)
    sensor_from_world = np.linalg.inv(poses[columns // 2])
    rings = len(model.elevations_deg)
    for mover, world_T_object in moving:
        now = world_T_object(np.zeros(1))[0]
        centre = (
            sensor_from_world[:3, :3] @ (now[:3, :3] @ mover.centre + now[:3, 3])
            + sensor_from_world[:3, 3]
        )
        cols = _window_columns(model, centre, mover.radius_m)
        object_poses = world_T_object(offset[cols])  # (C, 4, 4) at each column's firing
        picked = (np.arange(rings)[:, None] * columns + cols[None, :]).ravel()
        pose = np.tile(object_poses, (rings, 1, 1))
        rotation_t = np.swapaxes(pose[:, :3, :3], 1, 2)
        ray_origin = np.einsum("rij,rj->ri", rotation_t, origins[picked] - pose[:, :3, 3])
        ray_direction = np.einsum("rij,rj->ri", rotation_t, directions[picked])
        hits = _cast(mover.scene, ray_origin, ray_direction, threads)
        closer = hits["t_hit"] < t_hit[picked]
        chosen = picked[closer]
        t_hit[chosen] = hits["t_hit"][closer]
        normals[chosen] = np.einsum(
            "rij,rj->ri", pose[closer, :3, :3], hits["primitive_normals"][closer]
        )
        material[chosen] = mover.materials[hits["primitive_ids"][closer]]
        obj[chosen] = mover.index
    return _returns(model, local, directions, t_hit, material, obj, normals, rng)


def _materials(
    per_geometry: list[np.ndarray], geometry: np.ndarray, primitive: np.ndarray
) -> np.ndarray:
    """Each hit's material from its geometry's per-triangle table (one gather per geometry)."""
    out = np.empty(len(geometry), dtype=np.int64)
    for g in np.unique(geometry):
        rows = geometry == g
        out[rows] = per_geometry[g][primitive[rows]]
    return out


def _returns(
    model: LidarModel,
    local: np.ndarray,
    directions: np.ndarray,
    t_hit: np.ndarray,
    material: np.ndarray,
    obj: np.ndarray,
    normals: np.ndarray,
    rng: np.random.Generator,
) -> Scan:
    hit = np.isfinite(t_hit) & (material >= 0)
    reflectance = np.where(hit, REFLECTANCE[np.maximum(material, 0)], 0.0)
    incidence = np.abs(np.einsum("ri,ri->r", normals, directions))
    reach = 55.0 + 75.0 * reflectance  # dark paint fades long before a white sign
    range_m = t_hit + rng.normal(0.0, model.range_noise_m, len(t_hit))
    fading = np.clip(range_m / reach, 0, 1) ** 4 + np.where(incidence < 0.12, 0.5, 0.0)
    lost = np.where(hit, DROPOUT[np.maximum(material, 0)], 1.0) + model.base_dropout + fading
    keep = (
        hit
        & (rng.uniform(size=len(t_hit)) > lost)
        & (range_m >= model.min_range_m)
        & (range_m <= model.max_range_m)
    )
    rays = np.flatnonzero(keep)
    intensity = (
        reflectance[rays] * (0.7 + 0.3 * incidence[rays]) * rng.uniform(0.75, 1.25, len(rays))
    )
    intensity[rng.uniform(size=len(rays)) < DARK[material[rays]]] = 0.0
    points = np.column_stack([local[rays] * range_m[rays, None], np.clip(intensity, 0, 0.99)])
    return Scan(points.astype(np.float32), obj[rays], rays)
