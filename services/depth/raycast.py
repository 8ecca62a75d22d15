"""Rays against the scene's primitives, all rays of a chunk at once.

Every function takes ray origins ``(N, 3)`` and directions ``(N, 3)`` in the street frame
(metres, float32) and returns the ray parameter ``t`` of the nearest hit in front of the
origin (``inf`` for a miss), so a point is ``origin + t · direction``; with directions of
unit z in the camera frame, ``t`` is the depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.depth.scene import KERB, PAVEMENT, ROAD, Boxes, Cylinders, Ellipsoids, Street

EPSILON_M = 1e-3
Shapes = tuple[Boxes, Cylinders, Ellipsoids]


@dataclass(frozen=True)
class Hit:
    """The nearest hit of each ray on one family of primitives."""

    t: np.ndarray
    """(N,) ray parameter, inf for a miss."""
    index: np.ndarray
    """(N,) which primitive (for the ground: its material)."""
    normal: np.ndarray
    """(N, 3) unit surface normal (any side; the shader turns it to face the ray)."""
    u_m: np.ndarray
    """(N,) horizontal texture coordinate on the surface."""
    v_m: np.ndarray
    """(N,) vertical (height above the primitive's base) or second coordinate."""
    face: np.ndarray
    """(N,) 0 across, 1 top or bottom, 2 along (boxes' face axis; 0 elsewhere)."""


def _safe(d: np.ndarray) -> np.ndarray:
    return np.where(np.abs(d) < 1e-9, np.float32(1e-9), d)


def ground(origin: np.ndarray, direction: np.ndarray, street: Street) -> Hit:
    """The road (y = 0), the pavements (y = −kerb beyond ±road_half) and the kerbs' faces."""
    n = len(direction)
    dy = _safe(direction[:, 1])
    t_road = (0.0 - origin[:, 1]) / dy
    t_pave = (-street.kerb_m - origin[:, 1]) / dy
    x_road = origin[:, 0] + t_road * direction[:, 0]
    x_pave = origin[:, 0] + t_pave * direction[:, 0]
    road = (t_road > EPSILON_M) & (np.abs(x_road) <= street.road_half_m)
    pave = (t_pave > EPSILON_M) & (np.abs(x_pave) >= street.road_half_m)
    side = np.sign(np.where(np.abs(x_pave) > 0, x_pave, x_road))
    t_kerb = (side * street.road_half_m - origin[:, 0]) / _safe(direction[:, 0])
    y_kerb = origin[:, 1] + t_kerb * direction[:, 1]
    kerb = (t_kerb > EPSILON_M) & (y_kerb >= -street.kerb_m) & (y_kerb <= 0.0)
    t = np.full(n, np.inf, np.float32)
    material = np.full(n, ROAD, np.int64)
    normal = np.zeros((n, 3), np.float32)
    normal[:, 1] = -1.0
    for mask, t_here, kind in (
        (kerb, t_kerb, KERB),
        (road, t_road, ROAD),
        (pave, t_pave, PAVEMENT),
    ):
        nearer = mask & (t_here < t)
        t = np.where(nearer, t_here, t)
        material = np.where(nearer, kind, material)
    is_kerb = material == KERB
    normal[is_kerb] = 0.0
    normal[is_kerb, 0] = -side[is_kerb]
    point = origin + np.where(np.isfinite(t), t, 0)[:, None] * direction
    u = np.where(is_kerb, point[:, 2], point[:, 0])
    v = np.where(is_kerb, -point[:, 1], point[:, 2])
    return Hit(t.astype(np.float32), material, normal, u, v, np.zeros(n, np.int64))


def boxes(origin: np.ndarray, direction: np.ndarray, shapes: Boxes, time_s: float) -> Hit:
    """Oriented boxes (yaw about y) by the slab test, at ``time_s`` (moving boxes moved)."""
    n, count = len(direction), len(shapes.half_m)
    if count == 0:
        return _miss(n)
    centre = (shapes.centre_m + shapes.velocity_m_s * time_s).astype(np.float32)
    cos, sin = np.cos(shapes.yaw_rad).astype(np.float32), np.sin(shapes.yaw_rad).astype(np.float32)
    # the box's axes in the street frame: x across (cos, 0, −sin), y, z along (sin, 0, cos)
    rel = origin[:, None, :] - centre[None, :, :]
    o_local = np.stack(
        (rel[..., 0] * cos - rel[..., 2] * sin, rel[..., 1], rel[..., 0] * sin + rel[..., 2] * cos),
        axis=-1,
    )
    dx, dy, dz = direction[:, 0:1], direction[:, 1:2], direction[:, 2:3]
    d_local = np.stack(
        (dx * cos - dz * sin, np.broadcast_to(dy, (n, count)), dx * sin + dz * cos), axis=-1
    )
    d_local = _safe(d_local)
    half = shapes.half_m.astype(np.float32)[None]
    t1 = (-half - o_local) / d_local
    t2 = (half - o_local) / d_local
    near = np.minimum(t1, t2)
    far = np.maximum(t1, t2)
    t_near = np.maximum(np.maximum(near[..., 0], near[..., 1]), near[..., 2])
    t_far = np.minimum(np.minimum(far[..., 0], far[..., 1]), far[..., 2])
    hit = (t_near <= t_far) & (t_near > EPSILON_M)
    t_all = np.where(hit, t_near, np.inf)
    index = t_all.argmin(axis=1)
    rows = np.arange(n)
    t = t_all[rows, index]
    face = near[rows, index].argmax(axis=-1)
    sign = -np.sign(d_local[rows, index, face])
    normal_local = np.zeros((n, 3), np.float32)
    normal_local[rows, face] = sign
    c, s = cos[index], sin[index]
    normal = np.stack(
        (
            normal_local[:, 0] * c + normal_local[:, 2] * s,
            normal_local[:, 1],
            -normal_local[:, 0] * s + normal_local[:, 2] * c,
        ),
        axis=-1,
    )
    finite_t = np.where(np.isfinite(t), t, 0)[:, None]
    local = o_local[rows, index] + finite_t * d_local[rows, index]
    h = half[0, index]
    height = h[:, 1] - local[:, 1]
    u = np.where(face == 0, local[:, 2] + h[:, 2], local[:, 0] + h[:, 0])
    v = np.where(face == 1, local[:, 2] + h[:, 2], height)
    return Hit(t.astype(np.float32), index, normal.astype(np.float32), u, v, face)


def cylinders(origin: np.ndarray, direction: np.ndarray, shapes: Cylinders) -> Hit:
    """Vertical cylinders (their sides)."""
    n, count = len(direction), len(shapes.radius_m)
    if count == 0:
        return _miss(n)
    centre = shapes.centre_xz_m.astype(np.float32)
    ox = origin[:, 0:1] - centre[None, :, 0]
    oz = origin[:, 2:3] - centre[None, :, 1]
    dx, dz = direction[:, 0:1], direction[:, 2:3]
    a = np.maximum(dx * dx + dz * dz, 1e-12)
    b = 2 * (ox * dx + oz * dz)
    c = ox * ox + oz * oz - shapes.radius_m.astype(np.float32)[None] ** 2
    disc = b * b - 4 * a * c
    t_all = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    y = origin[:, 1:2] + t_all * direction[:, 1:2]
    hit = (
        (disc > 0)
        & (t_all > EPSILON_M)
        & (y >= shapes.top_y_m[None])
        & (y <= shapes.bottom_y_m[None])
    )
    t_all = np.where(hit, t_all, np.inf)
    index = t_all.argmin(axis=1)
    rows = np.arange(n)
    t = t_all[rows, index]
    finite_t = np.where(np.isfinite(t), t, 0)
    px = ox[rows, index] + finite_t * dx[:, 0]
    pz = oz[rows, index] + finite_t * dz[:, 0]
    radius = shapes.radius_m[index].astype(np.float32)
    normal = np.stack((px / radius, np.zeros(n, np.float32), pz / radius), axis=-1)
    u = np.arctan2(pz, px) * radius
    v = shapes.bottom_y_m[index] - (origin[:, 1] + finite_t * direction[:, 1])
    return Hit(t.astype(np.float32), index, normal.astype(np.float32), u, v, np.zeros(n, np.int64))


def ellipsoids(origin: np.ndarray, direction: np.ndarray, shapes: Ellipsoids) -> Hit:
    """Axis-aligned ellipsoids (a unit sphere once scaled by the radii)."""
    n, count = len(direction), len(shapes.radii_m)
    if count == 0:
        return _miss(n)
    radii = shapes.radii_m.astype(np.float32)
    centre = shapes.centre_m.astype(np.float32)
    # per axis (small last axes reduce slowly in numpy: the three components are written out)
    o = [(origin[:, k : k + 1] - centre[None, :, k]) / radii[None, :, k] for k in range(3)]
    d = [direction[:, k : k + 1] / radii[None, :, k] for k in range(3)]
    a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    b = 2 * (o[0] * d[0] + o[1] * d[1] + o[2] * d[2])
    c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - 1
    disc = b * b - 4 * a * c
    t_all = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    t_all = np.where((disc > 0) & (t_all > EPSILON_M), t_all, np.inf)
    index = t_all.argmin(axis=1)
    rows = np.arange(n)
    t = t_all[rows, index]
    finite_t = np.where(np.isfinite(t), t, 0)[:, None]
    point = origin + finite_t * direction
    local = (point - centre[index]) / radii[index]
    normal = local / radii[index]
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
    u = point[:, 0] + 0.7 * point[:, 2]
    v = -point[:, 1] + 0.3 * point[:, 2]
    return Hit(t.astype(np.float32), index, normal.astype(np.float32), u, v, np.zeros(n, np.int64))


def _miss(n: int) -> Hit:
    zeros = np.zeros(n, np.float32)
    return Hit(
        np.full(n, np.inf, np.float32),
        np.zeros(n, np.int64),
        np.zeros((n, 3), np.float32),
        zeros,
        zeros,
        np.zeros(n, np.int64),
    )


def blocked(origin: np.ndarray, direction: np.ndarray, shapes: Shapes, time_s: float) -> np.ndarray:
    """(N,) bool: whether a ray meets any box, cylinder or ellipsoid (a shadow ray)."""
    box, cylinder, ellipsoid = shapes
    return (
        np.isfinite(boxes(origin, direction, box, time_s).t)
        | np.isfinite(cylinders(origin, direction, cylinder).t)
        | np.isfinite(ellipsoids(origin, direction, ellipsoid).t)
    )


def bounding_spheres(shapes: Shapes, time_s: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each family's (centres (P, 3), radii (P,)) enclosing its primitives at ``time_s``."""
    box, cylinder, ellipsoid = shapes
    mid_y = (cylinder.top_y_m + cylinder.bottom_y_m) / 2
    return [
        (box.centre_m + box.velocity_m_s * time_s, np.linalg.norm(box.half_m, axis=1)),
        (
            np.stack((cylinder.centre_xz_m[:, 0], mid_y, cylinder.centre_xz_m[:, 1]), axis=-1),
            np.hypot(cylinder.radius_m, (cylinder.bottom_y_m - cylinder.top_y_m) / 2),
        ),
        (
            ellipsoid.centre_m,
            ellipsoid.radii_m.max(axis=1) if len(ellipsoid.radii_m) else np.zeros(0),
        ),
    ]


def subset(shapes: Shapes, keep: list[np.ndarray]) -> Shapes:
    """The primitives of each family that ``keep`` (a bool or index array per family) selects."""
    return tuple(
        type(family)(
            **{name: getattr(family, name)[chosen] for name in family.__dataclass_fields__}
        )
        for family, chosen in zip(shapes, keep, strict=True)
    )


def in_cone(
    spheres: list[tuple[np.ndarray, np.ndarray]],
    apex: np.ndarray,
    axis: np.ndarray,
    half_angle_rad: float,
) -> list[np.ndarray]:
    """Which spheres a cone of rays from ``apex`` around unit ``axis`` may meet."""
    keep = []
    for centre, radius in spheres:
        w = centre - apex
        distance = np.linalg.norm(w, axis=1)
        inside = distance <= radius
        cosine = (w * axis).sum(1) / np.maximum(distance, 1e-9)
        angle = np.arccos(np.clip(cosine, -1, 1)) - np.arcsin(
            np.clip(radius / np.maximum(distance, 1e-9), 0, 1)
        )
        keep.append(inside | (angle <= half_angle_rad))
    return keep


def near_beam(
    spheres: list[tuple[np.ndarray, np.ndarray]],
    centre: np.ndarray,
    reach_m: float,
    direction: np.ndarray,
) -> list[np.ndarray]:
    """Which spheres parallel rays along unit ``direction`` from points within ``reach_m``
    of ``centre`` may meet."""
    keep = []
    for sphere, radius in spheres:
        w = sphere - centre
        along = w @ direction
        across = np.linalg.norm(w - along[:, None] * direction, axis=1)
        keep.append((across <= reach_m + radius) & (along >= -(reach_m + radius)))
    return keep
