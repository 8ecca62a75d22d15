"""Rendering a driving scene: a colour image and its dense depth from one camera pose.

Rays are cast in chunks against every primitive (``raycast``); the nearest hit's surface is
textured by its material (``textures``, in surface coordinates, so stereo and video see the
same texture), lit by the sun with cast shadows and by the sky, tone-mapped and given the
sensor's vignetting and noise. Depth is the hit's z in the camera frame; the sky has none (0).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from services.depth import raycast
from services.depth.camera import PinholeCamera
from services.depth.scene import (
    CABIN,
    CAR,
    CONCRETE,
    FOLIAGE,
    KERB,
    PAVEMENT,
    POLE,
    ROAD,
    TRUCK,
    TRUNK,
    WALL,
    Scene,
)
from services.depth.textures import boxes as window_grid
from services.depth.textures import fbm, grid_lines, value_noise

TILE = (32, 64)
"""Rows and columns of pixels cast together."""
GLASS = 0.03
"""Albedo of windows (what they reflect is added as sky light)."""


@dataclass(frozen=True)
class Rendering:
    image: np.ndarray
    """(H, W, 3) uint8 RGB."""
    depth_m: np.ndarray
    """(H, W) float32 depth along the optical axis; 0 where the ray meets only sky."""


@dataclass(frozen=True)
class _Surface:
    """Where each ray of a chunk ended: which family (0 sky, 1 ground, 2 box, 3 cylinder,
    4 ellipsoid), the hit of that family, and the material."""

    t: np.ndarray
    family: np.ndarray
    index: np.ndarray
    material: np.ndarray
    normal: np.ndarray
    u_m: np.ndarray
    v_m: np.ndarray
    face: np.ndarray
    colour: np.ndarray
    seed: np.ndarray


def _nearest(scene: Scene, origin: np.ndarray, direction: np.ndarray, time_s: float) -> _Surface:
    families = (scene.boxes, scene.cylinders, scene.ellipsoids)
    hits = (
        raycast.ground(origin, direction, scene.street),
        raycast.boxes(origin, direction, scene.boxes, time_s),
        raycast.cylinders(origin, direction, scene.cylinders),
        raycast.ellipsoids(origin, direction, scene.ellipsoids),
    )
    ts = np.stack([h.t for h in hits])
    which = ts.argmin(axis=0)
    rows = np.arange(len(direction))
    t = ts[which, rows]

    def pick(values: list[np.ndarray]) -> np.ndarray:
        return np.stack(values)[which, rows]

    index = pick([h.index for h in hits])
    street = scene.street
    ground_colour = np.stack((street.road_colour, street.pavement_colour, street.kerb_colour))
    materials, colours, seeds = (
        [index],
        [ground_colour[np.clip(index, 0, 2)]],
        [np.full(len(t), scene.seed)],
    )
    for shapes in families:
        # a family without primitives only has misses: any value serves
        safe = np.minimum(index, max(len(shapes.material) - 1, 0))
        present = len(shapes.material) > 0
        materials.append(shapes.material[safe] if present else index)
        colours.append(shapes.colour[safe] if present else np.zeros((len(t), 3), np.float32))
        seeds.append(shapes.seed[safe] if present else index)
    return _Surface(
        t=t,
        family=np.where(np.isfinite(t), which + 1, 0),
        index=index,
        material=pick(materials),
        normal=pick([h.normal for h in hits]),
        u_m=pick([h.u_m for h in hits]),
        v_m=pick([h.v_m for h in hits]),
        face=pick([h.face for h in hits]),
        colour=pick(colours),
        seed=pick(seeds),
    )


def _hashed(seed: np.ndarray, salt: int, low: float, high: float) -> np.ndarray:
    """A per-primitive random number in [low, high) from its seed (no per-pixel RNG)."""
    mixed = (seed.astype(np.uint64) * np.uint64(2654435761) + np.uint64(salt * 40503)) % np.uint64(
        1 << 31
    )
    return low + (high - low) * (mixed.astype(np.float64) / float(1 << 31)).astype(np.float32)


def _albedo(scene: Scene, s: _Surface, footprint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) albedo and (N,) glass coverage (what reflects the sky) of every hit."""
    n = len(s.t)
    albedo = s.colour.astype(np.float32).copy()
    glass = np.zeros(n, np.float32)
    u, v, fp, seed = s.u_m, s.v_m, footprint, int(scene.seed)
    street = scene.street

    def grain(mask: np.ndarray, scale_m: float, amount: float, salt: int, octaves: int = 4) -> None:
        if mask.any():
            noise = fbm(
                u[mask],
                v[mask],
                seed=seed + salt,
                scale_m=scale_m,
                footprint_m=fp[mask],
                octaves=octaves,
            )
            albedo[mask] *= (1 + amount * noise)[:, None]

    road = s.material == ROAD
    if road.any():
        grain(road, 4.0, 0.5, 1, 3)
        grain(road, 0.1, 0.35, 2, 3)
        x, z, f = u[road], v[road], fp[road]
        lanes = street.lanes
        boundaries = (np.arange(1, lanes) - lanes / 2) * street.lane_width_m
        period = street.dash_m + street.dash_gap_m
        dash = np.clip(
            (street.dash_m / 2 - np.abs((z % period) - street.dash_m / 2)) / np.maximum(f, 1e-3)
            + 0.5,
            0,
            1,
        )
        paint = np.zeros(len(x), np.float32)
        for boundary in boundaries:
            paint = np.maximum(paint, grid_lines(x - boundary, 1e6, 0.14, f) * dash)
        for edge in (-street.road_half_m + 0.3, street.road_half_m - 0.3):
            paint = np.maximum(paint, grid_lines(x - edge, 1e6, 0.15, f))
        wear = value_noise(x / 0.7, z / 0.7, seed + 3) < street.marking_wear * 0.8
        paint = paint * np.where(wear, 0.35, 1.0)
        albedo[road] = albedo[road] * (1 - paint[:, None]) + 0.75 * paint[:, None]
    pave = s.material == PAVEMENT
    if pave.any():
        grain(pave, 2.0, 0.3, 4, 5)
        grout = np.maximum(
            grid_lines(u[pave], street.tile_m, 0.012, fp[pave]),
            grid_lines(v[pave], street.tile_m, 0.012, fp[pave]),
        )
        albedo[pave] *= (1 - 0.45 * grout)[:, None]
    grain(s.material == KERB, 0.5, 0.25, 5)
    wall = s.material == WALL
    if wall.any():
        grain(wall, 3.0, 0.3, 6)
        side = wall & (s.face != 1)
        sw = s.seed[side]
        period_x = _hashed(sw, 1, 2.2, 4.5)
        period_y = _hashed(sw, 2, 2.8, 3.6)
        width = period_x * _hashed(sw, 3, 0.35, 0.7)
        height = period_y * _hashed(sw, 4, 0.4, 0.65)
        windows = window_grid(
            u[side],
            v[side],
            period_m=(period_x, period_y),
            size_m=(width, height),
            offset_m=(_hashed(sw, 5, 0, 2), _hashed(sw, 6, 0.8, 1.2)),
            footprint_m=fp[side],
        )
        windows *= (v[side] > 0.7).astype(np.float32)
        tint = GLASS * (0.6 + 0.8 * value_noise(u[side] / 3.0, v[side] / 3.0, seed + 7))
        albedo[side] = albedo[side] * (1 - windows[:, None]) + tint[:, None] * windows[:, None]
        glass[side] = windows * 0.6
        roof = wall & (s.face == 1)
        albedo[roof] *= 0.6
    car = s.material == CAR
    if car.any():
        grain(car, 1.0, 0.06, 8, 2)
        sides = car & (s.face == 0)
        length = 2 * scene.boxes.half_m[s.index[sides], 2].astype(np.float32)
        wheel_u = np.minimum(np.abs(u[sides] - 0.8), np.abs(u[sides] - (length - 0.8)))
        wheel = np.clip(
            (0.33 - np.hypot(wheel_u, v[sides] - 0.12)) / np.maximum(fp[sides], 1e-3), 0, 1
        )
        albedo[sides] = albedo[sides] * (1 - wheel[:, None]) + 0.04 * wheel[:, None]
        low = car & (s.face != 1) & (v < 0.12)
        albedo[low] *= 0.35
        ends = car & (s.face == 2)
        lamp = window_grid(
            u[ends],
            v[ends],
            period_m=(1.35, 10.0),
            size_m=(0.25, 0.12),
            offset_m=(0.1, 0.55),
            footprint_m=fp[ends],
        )
        albedo[ends] = (
            albedo[ends] * (1 - lamp[:, None])
            + np.array([0.7, 0.15, 0.1], np.float32) * lamp[:, None]
        )
    cabin = s.material == CABIN
    if cabin.any():
        vertical = cabin & (s.face != 1)
        inset = np.clip(
            np.minimum(v[vertical] - 0.04, 0.5 - v[vertical]) / np.maximum(fp[vertical], 1e-3), 0, 1
        )
        albedo[vertical] = albedo[vertical] * (1 - inset[:, None]) + GLASS * inset[:, None]
        glass[vertical] = inset * 0.8
    grain(s.material == TRUCK, 2.0, 0.25, 9)
    grain(s.material == CONCRETE, 1.5, 0.35, 10)
    grain(s.material == POLE, 0.5, 0.1, 11, 2)
    grain(s.material == TRUNK, 0.15, 0.5, 12)
    leaves = s.material == FOLIAGE
    if leaves.any():
        grain(leaves, 1.5, 0.5, 13, 2)
        grain(leaves, 0.12, 1.2, 14, 3)
    return np.clip(albedo, 0.0, 1.0), glass


def sky(scene: Scene, direction: np.ndarray) -> np.ndarray:
    """(N, 3) sky radiance along unit directions (street frame)."""
    light = scene.lighting
    up = np.clip(-direction[:, 1], 0, 1)
    blend = np.sqrt(np.clip(up * 3.0, 0, 1))[:, None]
    colour = light.horizon * (1 - blend) + light.zenith * blend
    high = np.maximum(up, 0.03)
    cu, cv = direction[:, 0] / high * 300, direction[:, 2] / high * 300
    cloud = fbm(
        cu,
        cv,
        seed=scene.seed + 50,
        scale_m=400.0,
        footprint_m=np.full(len(up), 1.0, np.float32),
        octaves=4,
    )
    cover = np.clip((cloud + light.clouds - 0.3) * 3, 0, 1)[:, None]
    colour = colour * (1 - cover) + 1.1 * cover
    glow = np.exp(-(1 - np.clip(direction @ light.sun_direction, -1, 1)) * 40)[:, None]
    return (colour + glow * light.sun * 0.3).astype(np.float32)


def _shade(
    scene: Scene,
    s: _Surface,
    origin: np.ndarray,
    direction: np.ndarray,
    pixel_m: np.ndarray,
    time_s: float,
    occluders: tuple[raycast.Shapes, list] | None,
) -> np.ndarray:
    """Radiance of each ray: the sky's, or its surface's lit by the sun (blocked by
    ``occluders`` — every primitive and its bounding sphere — unless None) and the sky."""
    unit = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    radiance = sky(scene, unit)
    solid = s.family > 0
    if not solid.any():
        return radiance
    normal = s.normal[solid]
    facing = np.sign((normal * unit[solid]).sum(1))
    normal = normal * np.where(facing > 0, -1.0, 1.0)[:, None]
    cosine = np.abs((normal * unit[solid]).sum(1))
    surface = _Surface(*(getattr(s, name)[solid] for name in _Surface.__dataclass_fields__))
    footprint = pixel_m[solid] / np.sqrt(np.maximum(cosine, 0.03))
    albedo, glass = _albedo(scene, surface, footprint.astype(np.float32))
    light = scene.lighting
    lambert = np.clip(normal @ light.sun_direction, 0, 1).astype(np.float32)
    point = origin[solid] + s.t[solid, None] * direction[solid]
    lit_candidates = lambert > 0
    if occluders is not None and lit_candidates.any():
        start = point[lit_candidates] + normal[lit_candidates] * 0.02
        shapes, spheres = occluders
        middle = start.mean(axis=0)
        reach = float(np.linalg.norm(start - middle, axis=1).max())
        near = raycast.subset(
            shapes, raycast.near_beam(spheres, middle, reach, light.sun_direction)
        )
        towards = np.broadcast_to(light.sun_direction.astype(np.float32), start.shape)
        shade = raycast.blocked(start, towards, near, time_s)
        lambert[np.flatnonzero(lit_candidates)[shade]] = 0
    skylight = np.clip(0.55 - 0.45 * normal[:, 1], 0.2, 1.0)[:, None]
    lit = albedo * (light.ambient * skylight + light.sun * lambert[:, None])
    reflection = glass[:, None] * light.horizon * 0.06
    radiance[solid] = lit + reflection
    return radiance


def render(
    scene: Scene,
    camera: PinholeCamera,
    street_T_camera: np.ndarray,
    *,
    time_s: float = 0.0,
    noise_seed: int | None = 0,
    shadows: bool = True,
) -> Rendering:
    """The image and depth seen by ``camera`` at pose ``street_T_camera`` (4 × 4, metres)
    at ``time_s`` (moving cars moved); ``noise_seed`` None renders without sensor noise.

    The image is cast in tiles; each tile's rays only meet the primitives whose bounding
    spheres are inside its cone, and its shadow rays those near its beam to the sun."""
    rays = camera.rays()
    rotation = street_T_camera[:3, :3].astype(np.float32)
    origin_one = street_T_camera[:3, 3].astype(np.float32)
    directions = rays @ rotation.T
    length = np.linalg.norm(rays, axis=-1)
    focal = float(np.sqrt(camera.K[0, 0] * camera.K[1, 1]))
    shapes = (scene.boxes, scene.cylinders, scene.ellipsoids)
    spheres = raycast.bounding_spheres(shapes, time_s)
    occluders = (shapes, spheres) if shadows else None
    depth = np.zeros(rays.shape[:2], np.float32)
    radiance = np.zeros(rays.shape, np.float32)
    for top in range(0, camera.height, TILE[0]):
        for left in range(0, camera.width, TILE[1]):
            tile = (slice(top, top + TILE[0]), slice(left, left + TILE[1]))
            direction = directions[tile].reshape(-1, 3)
            unit = direction / np.linalg.norm(direction, axis=1, keepdims=True)
            axis = unit.mean(axis=0)
            axis /= np.linalg.norm(axis)
            half_angle = float(np.arccos(np.clip(unit @ axis, -1, 1)).max()) + 1e-3
            seen = raycast.subset(shapes, raycast.in_cone(spheres, origin_one, axis, half_angle))
            local = replace(scene, boxes=seen[0], cylinders=seen[1], ellipsoids=seen[2])
            origin = np.broadcast_to(origin_one, direction.shape)
            surface = _nearest(local, origin, direction, time_s)
            t = np.where(np.isfinite(surface.t), surface.t, 0.0)
            depth[tile] = t.reshape(depth[tile].shape)
            pixel_m = t * length[tile].reshape(-1) / focal
            shaded = _shade(local, surface, origin, direction, pixel_m, time_s, occluders)
            radiance[tile] = shaded.reshape(radiance[tile].shape)
    image = _expose(scene, camera, radiance, noise_seed)
    return Rendering(image, depth)


def _expose(
    scene: Scene, camera: PinholeCamera, radiance: np.ndarray, noise_seed: int | None
) -> np.ndarray:
    """Tone curve, vignetting, white balance and sensor noise, to 8 bits."""
    x = radiance * scene.lighting.exposure
    u = (np.arange(camera.width) - camera.width / 2) / camera.width
    v = (np.arange(camera.height) - camera.height / 2) / camera.width
    vignette = 1 - 0.35 * (u[None, :] ** 2 + v[:, None] ** 2)
    x = x * vignette[..., None]
    toned = (1 - np.exp(-1.8 * x)) / (1 - np.exp(-1.8 * 1.1))
    toned = np.clip(toned, 0, 1) ** (1 / 1.6)
    contrast = 1.0 + 0.4 * ((scene.seed * 0.6180339887) % 1.0)
    toned = np.clip(0.5 + (toned - 0.5) * contrast, 0, 1)
    if noise_seed is not None:
        rng = np.random.default_rng([scene.seed, noise_seed])
        balance = rng.uniform(0.94, 1.06, 3).astype(np.float32)
        sigma = (0.006 + 0.012 * np.sqrt(toned)).astype(np.float32)
        toned = toned * balance + sigma * rng.standard_normal(toned.shape, dtype=np.float32)
    return np.clip(np.rint(toned * 255), 0, 255).astype(np.uint8)
