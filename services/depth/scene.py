"""Random driving scenes: a straight street of lanes, kerbs and pavements, lined with
buildings, trees, hedges and poles, with parked cars, traffic, trucks and sometimes a bridge,
under a random sun and sky.

The street frame S is the camera's convention (x right, y down, z along the street, metres);
the road surface is the plane y = 0 and everything stands on it (negative y is up). Objects
are oriented boxes (buildings, car bodies and cabins, trucks, hedges, bridges), vertical
cylinders (poles, trunks) and ellipsoids (tree crowns, bushes); each has a material, a base
colour and a texture seed. Moving objects have a velocity along the street.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# materials
ROAD, PAVEMENT, KERB, WALL, CAR, CABIN, TRUCK, CONCRETE, POLE, TRUNK, FOLIAGE = range(11)

WALL_COLOURS = np.array(
    [
        [0.75, 0.70, 0.60],
        [0.85, 0.84, 0.80],
        [0.55, 0.28, 0.20],
        [0.50, 0.50, 0.52],
        [0.80, 0.70, 0.45],
        [0.65, 0.60, 0.55],
        [0.35, 0.33, 0.32],
        [0.75, 0.55, 0.45],
    ],
    np.float32,
)
CAR_COLOURS = np.array(
    [
        [0.85, 0.85, 0.85],
        [0.05, 0.05, 0.06],
        [0.55, 0.56, 0.58],
        [0.30, 0.31, 0.33],
        [0.55, 0.06, 0.05],
        [0.08, 0.15, 0.40],
        [0.70, 0.68, 0.60],
        [0.15, 0.30, 0.20],
    ],
    np.float32,
)


@dataclass(frozen=True)
class Boxes:
    centre_m: np.ndarray
    """(B, 3) float64, street frame."""
    half_m: np.ndarray
    """(B, 3) half sizes along the box's own x (across), y (up/down), z (along)."""
    yaw_rad: np.ndarray
    """(B,) rotation about the vertical (y) axis."""
    material: np.ndarray
    colour: np.ndarray
    """(B, 3) float32 albedo, 0–1."""
    seed: np.ndarray
    velocity_m_s: np.ndarray
    """(B, 3) motion of the box."""


@dataclass(frozen=True)
class Cylinders:
    centre_xz_m: np.ndarray
    """(C, 2) axis position."""
    radius_m: np.ndarray
    top_y_m: np.ndarray
    """(C,) the top's y (negative: above the road)."""
    bottom_y_m: np.ndarray
    material: np.ndarray
    colour: np.ndarray
    seed: np.ndarray


@dataclass(frozen=True)
class Ellipsoids:
    centre_m: np.ndarray
    radii_m: np.ndarray
    material: np.ndarray
    colour: np.ndarray
    seed: np.ndarray


@dataclass(frozen=True)
class Street:
    road_half_m: float
    kerb_m: float
    lane_width_m: float
    lanes: int
    dash_m: float
    dash_gap_m: float
    road_colour: np.ndarray
    pavement_colour: np.ndarray
    kerb_colour: np.ndarray
    marking_wear: float
    """0 = fresh white paint, 1 = none left."""
    tile_m: float


@dataclass(frozen=True)
class Lighting:
    sun_direction: np.ndarray
    """(3,) unit vector towards the sun, street frame (y down: its y is negative)."""
    sun: np.ndarray
    """(3,) sunlight's colour and strength."""
    ambient: np.ndarray
    """(3,) skylight on an upward surface."""
    horizon: np.ndarray
    zenith: np.ndarray
    clouds: float
    exposure: float


@dataclass(frozen=True)
class Scene:
    street: Street
    boxes: Boxes
    cylinders: Cylinders
    ellipsoids: Ellipsoids
    lighting: Lighting
    seed: int
    ego_x_m: float
    """The centre of the lane the camera drives in (kept free of parked cars and traffic
    near the start)."""


class _Collector:
    """Gathers primitives while a scene is laid out."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.boxes: list[tuple] = []
        self.cylinders: list[tuple] = []
        self.ellipsoids: list[tuple] = []

    def seed(self) -> int:
        return int(self.rng.integers(1 << 30))

    def box(self, centre, half, material, colour, yaw=0.0, velocity=(0.0, 0.0, 0.0)) -> None:  # noqa: ANN001 - sequences of floats
        self.boxes.append((centre, half, yaw, material, colour, self.seed(), velocity))

    def cylinder(self, x, z, radius, top, bottom, material, colour) -> None:  # noqa: ANN001 - floats
        self.cylinders.append(((x, z), radius, top, bottom, material, colour, self.seed()))

    def ellipsoid(self, centre, radii, material, colour) -> None:  # noqa: ANN001 - sequences
        self.ellipsoids.append((centre, radii, material, colour, self.seed()))

    def build(self) -> tuple[Boxes, Cylinders, Ellipsoids]:
        b, c, e = self.boxes, self.cylinders, self.ellipsoids
        boxes = Boxes(
            np.array([x[0] for x in b], np.float64).reshape(-1, 3),
            np.array([x[1] for x in b], np.float64).reshape(-1, 3),
            np.array([x[2] for x in b], np.float64),
            np.array([x[3] for x in b], np.int64),
            np.array([x[4] for x in b], np.float32).reshape(-1, 3),
            np.array([x[5] for x in b], np.int64),
            np.array([x[6] for x in b], np.float64).reshape(-1, 3),
        )
        cylinders = Cylinders(
            np.array([x[0] for x in c], np.float64).reshape(-1, 2),
            np.array([x[1] for x in c], np.float64),
            np.array([x[2] for x in c], np.float64),
            np.array([x[3] for x in c], np.float64),
            np.array([x[4] for x in c], np.int64),
            np.array([x[5] for x in c], np.float32).reshape(-1, 3),
            np.array([x[6] for x in c], np.int64),
        )
        ellipsoids = Ellipsoids(
            np.array([x[0] for x in e], np.float64).reshape(-1, 3),
            np.array([x[1] for x in e], np.float64).reshape(-1, 3),
            np.array([x[2] for x in e], np.int64),
            np.array([x[3] for x in e], np.float32).reshape(-1, 3),
            np.array([x[4] for x in e], np.int64),
        )
        return boxes, cylinders, ellipsoids


def _tint(rng: np.random.Generator, colour: np.ndarray, spread: float = 0.08) -> np.ndarray:
    return np.clip(colour * rng.uniform(1 - spread, 1 + spread, 3), 0.02, 0.95)


def _car(out: _Collector, x: float, z: float, yaw: float, speed: float) -> None:
    """A car: a body and a narrower cabin, its length along the street."""
    rng = out.rng
    length, width = rng.uniform(3.8, 4.9), rng.uniform(1.65, 1.9)
    body_h, cabin_h = rng.uniform(0.75, 1.0), rng.uniform(0.45, 0.6)
    clearance = 0.18
    colour = _tint(rng, CAR_COLOURS[rng.integers(len(CAR_COLOURS))], 0.05)
    velocity = (speed * np.sin(yaw), 0.0, speed * np.cos(yaw))
    out.box(
        (x, -(clearance + body_h / 2), z),
        (width / 2, body_h / 2, length / 2),
        CAR,
        colour,
        yaw,
        velocity,
    )
    cabin_len = length * rng.uniform(0.45, 0.6)
    shift = rng.uniform(-0.25, 0.05) * length
    out.box(
        (x + shift * np.sin(yaw), -(clearance + body_h + cabin_h / 2), z + shift * np.cos(yaw)),
        (width / 2 - 0.08, cabin_h / 2, cabin_len / 2),
        CABIN,
        colour,
        yaw,
        velocity,
    )


def _truck(out: _Collector, x: float, z: float, speed: float) -> None:
    rng = out.rng
    length, width, height = rng.uniform(7, 14), rng.uniform(2.3, 2.55), rng.uniform(3.0, 4.0)
    colour = _tint(rng, WALL_COLOURS[rng.integers(len(WALL_COLOURS))], 0.15)
    velocity = (0.0, 0.0, speed)
    cab = rng.uniform(1.8, 2.3)
    out.box(
        (x, -(0.5 + (height - 0.5) / 2), z),
        (width / 2, (height - 0.5) / 2, length / 2),
        TRUCK,
        colour,
        0.0,
        velocity,
    )
    cab_colour = _tint(rng, CAR_COLOURS[rng.integers(len(CAR_COLOURS))], 0.05)
    out.box(
        (x, -(0.4 + 1.3), z - length / 2 - cab / 2 - 0.2),
        (width / 2, 1.3, cab / 2),
        CAR,
        cab_colour,
        0.0,
        velocity,
    )


def _tree(out: _Collector, x: float, z: float, foliage: np.ndarray, pavement_y: float) -> None:
    rng = out.rng
    trunk_h, crown_r = rng.uniform(1.8, 4.0), rng.uniform(1.2, 3.5)
    out.cylinder(
        x,
        z,
        rng.uniform(0.08, 0.25),
        pavement_y - trunk_h - crown_r * 0.5,
        pavement_y,
        TRUNK,
        _tint(rng, np.array([0.22, 0.16, 0.11]), 0.2),
    )
    out.ellipsoid(
        (x, pavement_y - trunk_h - crown_r * rng.uniform(0.6, 0.9), z),
        (crown_r, crown_r * rng.uniform(0.8, 1.5), crown_r),
        FOLIAGE,
        _tint(rng, foliage, 0.2),
    )


def _side(out: _Collector, sign: float, street: Street, length_m: float, kind: str) -> None:
    """One side of the street (sign +1 right, −1 left): pavement furniture and what stands
    behind it (buildings, vegetation or open land)."""
    rng = out.rng
    kerb_x = street.road_half_m
    pavement_w = rng.uniform(1.5, 5.0)
    pavement_y = -street.kerb_m
    foliage = np.array([rng.uniform(0.06, 0.2), rng.uniform(0.14, 0.32), rng.uniform(0.04, 0.12)])
    z = -30.0
    if kind == "buildings":
        while z < length_m:
            span = rng.uniform(8, 35)
            setback = pavement_w + (0.0 if rng.random() < 0.6 else rng.uniform(1, 8))
            height = rng.uniform(5, 25)
            depth = 12.0
            x = sign * (kerb_x + setback + depth / 2)
            out.box(
                (x, pavement_y - height / 2, z + span / 2),
                (depth / 2, height / 2, span / 2),
                WALL,
                _tint(rng, WALL_COLOURS[rng.integers(len(WALL_COLOURS))]),
            )
            z += span + (0.0 if rng.random() < 0.7 else rng.uniform(2, 10))
    elif kind == "vegetation":
        while z < length_m:
            span = rng.uniform(3, 12)
            distance = pavement_w + rng.uniform(0, 12)
            for _ in range(int(rng.integers(1, 4))):
                _tree(
                    out,
                    sign * (kerb_x + distance + rng.uniform(0, 6)),
                    z + rng.uniform(0, span),
                    foliage,
                    pavement_y,
                )
            if rng.random() < 0.5:
                r = rng.uniform(0.6, 1.6)
                out.ellipsoid(
                    (sign * (kerb_x + distance + r), pavement_y - r * 0.5, z + span / 2),
                    (r, r * 0.7, r * rng.uniform(1, 3)),
                    FOLIAGE,
                    _tint(rng, foliage, 0.25),
                )
            z += span
    # hedges, poles and trees on the pavement
    z = -30.0
    while z < length_m:
        z += rng.uniform(6, 25)
        choice = rng.random()
        edge = sign * (kerb_x + rng.uniform(0.4, 0.9))
        if choice < 0.35:
            _tree(out, edge, z, foliage, pavement_y)
        elif choice < 0.65:
            height = rng.uniform(4, 9)
            out.cylinder(
                edge,
                z,
                rng.uniform(0.05, 0.14),
                pavement_y - height,
                pavement_y,
                POLE,
                _tint(rng, np.array([0.35, 0.36, 0.37]), 0.3),
            )
        elif choice < 0.8:
            length, height = rng.uniform(3, 15), rng.uniform(0.7, 1.8)
            x = sign * (kerb_x + pavement_w - 0.5)
            out.box(
                (x, pavement_y - height / 2, z + length / 2),
                (0.5, height / 2, length / 2),
                FOLIAGE,
                _tint(rng, foliage, 0.2),
            )


def _traffic(
    out: _Collector, street: Street, lane_centres: np.ndarray, length_m: float, ego_lane: int
) -> None:
    rng = out.rng
    lanes = len(lane_centres)
    for lane, x in enumerate(lane_centres):
        outermost = lane in (0, lanes - 1)
        oncoming = lane < lanes // 2 and lanes > 2
        if outermost and lane != ego_lane and rng.random() < 0.55:
            # a parking lane: cars along the kerb, some gaps
            z = rng.uniform(-20, 5)
            kerb_side = 1.0 if lane == lanes - 1 else -1.0
            while z < length_m * 0.8:
                if rng.random() < 0.8:
                    _car(out, x + kerb_side * rng.uniform(0.2, 0.6), z, rng.normal(0, 0.03), 0.0)
                z += rng.uniform(5.0, 7.5) + (0 if rng.random() < 0.8 else rng.uniform(3, 15))
            continue
        z = rng.uniform(-25, 8) if lane != ego_lane else rng.uniform(6, 20)
        speed = rng.uniform(0, 14) * (-1 if oncoming else 1)
        while z < length_m * 0.7:
            if lane == ego_lane and abs(z) < 6:
                z += 8
                continue
            if rng.random() < 0.12:
                _truck(out, x, z, speed)
                z += 16
            else:
                _car(out, x + rng.normal(0, 0.2), z, rng.normal(0, 0.02), speed)
            z += rng.uniform(6, 30)


def random_scene(seed: int, length_m: float = 160.0) -> Scene:
    """A street ``length_m`` long ahead of the origin (and 30 m behind it), laid out and lit
    at random from ``seed``."""
    rng = np.random.default_rng([seed, 2024])
    lanes = int(rng.integers(2, 6))
    lane_w = rng.uniform(2.9, 3.7)
    road_half = lanes * lane_w / 2 + rng.uniform(0, 0.6)
    street = Street(
        road_half_m=road_half,
        kerb_m=rng.uniform(0.08, 0.18),
        lane_width_m=lane_w,
        lanes=lanes,
        dash_m=rng.uniform(2.5, 6),
        dash_gap_m=rng.uniform(4, 12),
        road_colour=_tint(rng, np.full(3, rng.uniform(0.12, 0.32)), 0.05),
        pavement_colour=_tint(rng, np.full(3, rng.uniform(0.3, 0.6)), 0.12),
        kerb_colour=_tint(rng, np.full(3, rng.uniform(0.35, 0.6)), 0.05),
        marking_wear=float(rng.uniform(0, 0.8)),
        tile_m=rng.uniform(0.25, 0.6),
    )
    lane_centres = (np.arange(lanes) - (lanes - 1) / 2) * lane_w
    out = _Collector(rng)
    kinds = ("buildings", "vegetation", "open")
    for sign in (-1.0, 1.0):
        _side(out, sign, street, length_m, kinds[rng.choice(3, p=[0.5, 0.35, 0.15])])
    ego_lane = int(rng.integers(lanes // 2, lanes)) if lanes > 2 else int(rng.integers(lanes))
    _traffic(out, street, lane_centres, length_m, ego_lane)
    if rng.random() < 0.2:
        z, clearance, thick = rng.uniform(20, 90), rng.uniform(4.5, 7), rng.uniform(0.8, 2)
        width = road_half + 30
        grey = _tint(rng, np.full(3, rng.uniform(0.4, 0.65)), 0.05)
        out.box(
            (0.0, -(clearance + thick / 2), z),
            (width, thick / 2, rng.uniform(4, 9)),
            CONCRETE,
            grey,
        )
        for sign in (-1.0, 1.0):
            out.box(
                (sign * (road_half + 1.5), -clearance / 2, z),
                (0.6, clearance / 2, 0.6),
                CONCRETE,
                grey,
            )
    boxes, cylinders, ellipsoids = out.build()
    elevation = np.radians(rng.uniform(15, 65))
    azimuth = rng.uniform(0, 2 * np.pi)
    overcast = rng.random() < 0.25
    sun_strength = rng.uniform(0.3, 0.8) if overcast else rng.uniform(1.8, 3.2)
    warm = np.array([1.0, rng.uniform(0.92, 1.0), rng.uniform(0.8, 0.95)])
    lighting = Lighting(
        sun_direction=np.array(
            [
                np.cos(elevation) * np.sin(azimuth),
                -np.sin(elevation),
                np.cos(elevation) * np.cos(azimuth),
            ]
        ),
        sun=sun_strength * warm,
        ambient=rng.uniform(0.5, 0.9) * np.array([0.85, 0.92, 1.1]) * (1.6 if overcast else 1.0),
        horizon=np.clip(np.array([0.85, 0.9, 0.95]) * rng.uniform(0.9, 1.2), 0, 1.3),
        zenith=np.array([0.35, 0.55, 0.9]) * rng.uniform(0.7, 1.1)
        if not overcast
        else np.full(3, 0.8),
        clouds=float(rng.uniform(0, 0.6)) if not overcast else 0.2,
        exposure=float(rng.uniform(0.6, 1.1)),
    )
    return Scene(
        street, boxes, cylinders, ellipsoids, lighting, seed, float(lane_centres[ego_lane])
    )
