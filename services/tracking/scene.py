"""A random street and the traffic on it, for the LiDAR simulator.

The road is a centreline of straights and arcs that rises and falls gently; positions on it
are (s, d): the distance along the centreline and the offset to its left (metres). Traffic
keeps to the right: lanes of the car's direction at d < 0, oncoming ones at d > 0, a bike
lane and sometimes a parking lane each side, then kerbs, pavements, and beyond them
buildings, hedges, fences, trees, bushes and poles.

Cars drive their lanes by the Intelligent Driver Model (each wants its own speed, stops
now and then as at lights, keeps its distance to the one ahead), so the car the ego car
follows stays ahead for the whole drive — the long tracklet where a tracker's drift shows.
Pedestrians walk the pavements and cyclists ride the bike lanes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from services.tracking import meshes
from services.tracking.meshes import Mesh

STEP_M = 1.0
LANE_WIDTH_M = 3.4
BIKE_LANE_M = 1.5
PARKING_M = 2.3
KERB_M = 0.13
SIM_DT_S = 0.05


@dataclass(frozen=True)
class Road:
    s: np.ndarray
    """(S,) distance along the centreline, metres, every ``STEP_M``."""
    xy: np.ndarray
    heading: np.ndarray
    """(S,) unwrapped heading of the centreline, radians."""
    ground_z: np.ndarray
    lanes: int
    """Lanes each way."""
    parking: tuple[bool, bool]
    """A parking lane on the right, on the left."""
    pavement_m: tuple[float, float]
    barriers: tuple[str, str] = ("", "")
    """A rural road's edges, right and left: "guardrail", "concrete", "verge" (urban: "")."""

    @property
    def rural(self) -> bool:
        return bool(self.barriers[0])

    def pitch(self, s: np.ndarray) -> np.ndarray:
        """The road's slope along s (radians, positive rising)."""
        grade = np.gradient(self.ground_z, self.s)
        return np.arctan(np.interp(np.asarray(s, dtype=np.float64), self.s, grade))

    def edge(self, side: int) -> float:
        """|d| of the kerb on the right (side −1) or the left (+1)."""
        parking = self.parking[0 if side < 0 else 1]
        return self.lanes * LANE_WIDTH_M + BIKE_LANE_M + PARKING_M * parking

    def lane_offset(self, lane: int, direction: int) -> float:
        """d of the centre of lane ``lane`` (0 = next to the centreline) going ``direction``."""
        return -direction * (lane + 0.5) * LANE_WIDTH_M

    def pose(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(…, 2) world xy, (…,) ground z and (…,) the centreline's heading at (s, d)."""
        s = np.clip(np.asarray(s, dtype=np.float64), self.s[0], self.s[-1])
        heading = np.interp(s, self.s, self.heading)
        x = np.interp(s, self.s, self.xy[:, 0]) - np.sin(heading) * d
        y = np.interp(s, self.s, self.xy[:, 1]) + np.cos(heading) * d
        return np.stack([x, y], axis=-1), np.interp(s, self.s, self.ground_z), heading


def placements(
    xy: np.ndarray, z: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, lift_m: float = 0.0
) -> np.ndarray:
    """(K, 4, 4) world_T_object of things standing on the road at (xy, z): turned by ``yaw``
    about the vertical, tilted by ``pitch`` (nose up) about their own y axis, their origin
    ``lift_m`` up their own z axis."""
    count = len(yaw)
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    out = np.tile(np.eye(4), (count, 1, 1))
    # Rz(yaw) · Ry(−pitch): x forward and up the slope, z the slope's normal
    out[:, 0, 0], out[:, 0, 1], out[:, 0, 2] = cy * cp, -sy, -cy * sp
    out[:, 1, 0], out[:, 1, 1], out[:, 1, 2] = sy * cp, cy, -sy * sp
    out[:, 2, 0], out[:, 2, 1], out[:, 2, 2] = sp, 0.0, cp
    out[:, :3, 3] = np.column_stack([xy, z]) + lift_m * out[:, :3, 2]
    return out


def random_road(length_m: float, rng: np.random.Generator) -> Road:
    """Straights and arcs (radius 120–500 m), slopes of up to ±5 % (things on the road tilt
    with it), an urban street (pavements, parking) or a rural road (a guard rail, a concrete
    barrier or a verge at each edge)."""
    s = np.arange(0.0, length_m + STEP_M, STEP_M)
    curvature = np.zeros_like(s)
    start = 0.0
    while start < length_m:
        stretch = rng.uniform(40, 160)
        if rng.uniform() < 0.45:
            curvature[(s >= start) & (s < start + stretch)] = rng.choice([-1, 1]) / rng.uniform(
                120, 500
            )
        start += stretch
    heading = rng.uniform(-np.pi, np.pi) + np.concatenate(
        [[0.0], np.cumsum(curvature[:-1] * STEP_M)]
    )
    xy = np.column_stack(
        [
            np.concatenate([[0.0], np.cumsum(np.cos(heading[:-1]) * STEP_M)]),
            np.concatenate([[0.0], np.cumsum(np.sin(heading[:-1]) * STEP_M)]),
        ]
    )
    grade = sum(
        rng.uniform(0.0, amplitude)
        * np.sin(2 * np.pi * s / rng.uniform(*period) + rng.uniform(0, 6.3))
        for amplitude, period in ((0.035, (300, 700)), (0.015, (80, 200)))
    )
    ground_z = np.concatenate([[0.0], np.cumsum(grade[:-1] * STEP_M)])
    rural = rng.uniform() < 0.35
    barriers = (
        tuple(
            str(rng.choice(["guardrail", "concrete", "verge"], p=[0.45, 0.2, 0.35]))
            for _ in range(2)
        )
        if rural
        else ("", "")
    )
    return Road(
        s,
        xy,
        heading,
        ground_z,
        lanes=int(rng.choice([1, 2], p=[0.55, 0.45])),
        parking=(bool(rng.uniform() < 0.6) and not rural, bool(rng.uniform() < 0.4) and not rural),
        pavement_m=(0.0, 0.0) if rural else (rng.uniform(2.0, 4.5), rng.uniform(2.0, 4.5)),
        barriers=barriers,
    )


@dataclass
class Agent:
    """A labelled object: its type, mesh and where it is at each frame."""

    type: str
    """KITTI's: Car, Van, Pedestrian, Cyclist."""
    mesh: Mesh
    s: np.ndarray
    """(F,) metres along the road at each frame."""
    d: np.ndarray
    """(F,) offset, metres."""
    direction: int
    """+1 along the road, −1 against it."""
    lift_m: float = 0.0
    """Height above the road (pavements)."""
    shape: str = ""
    yaw_offset: float = 0.0
    """Turned from the direction of travel (cars parked across the road's direction)."""

    def poses(self, road: Road, frames: np.ndarray) -> np.ndarray:
        """(K, 4, 4) world_T_object at (fractional) frames."""
        frames = np.atleast_1d(np.asarray(frames, dtype=np.float64))
        index = np.arange(len(self.s))
        s = np.interp(frames, index, self.s)
        d = np.interp(frames, index, self.d)
        xy, z, heading = road.pose(s, d)
        step = np.interp(frames + 0.5, index, self.s) - np.interp(frames - 0.5, index, self.s)
        swerve = np.interp(frames + 0.5, index, self.d) - np.interp(frames - 0.5, index, self.d)
        yaw = heading + (0.0 if self.direction > 0 else np.pi) + self.yaw_offset
        # moving: face where it goes (a lane change turns it a little)
        yaw = yaw + np.where(
            np.abs(step) > 0.05, np.arctan2(swerve * self.direction, np.abs(step)), 0.0
        )
        pitch = road.pitch(s) * np.cos(yaw - heading)  # nose down when facing downhill
        return placements(xy, z, yaw, pitch, self.lift_m)

    def pose(self, road: Road, frame: float) -> np.ndarray:
        """world_T_object (4, 4) at a (fractional) frame."""
        return self.poses(road, np.array([frame]))[0]


@dataclass
class Street:
    road: Road
    static_meshes: list[Mesh]
    agents: list[Agent]
    ego_s: np.ndarray
    ego_d: float
    moving: np.ndarray
    """(A,) bool: the agent moves (cast per slice of the turn) or stands (cast with the
    street)."""
    notes: dict = field(default_factory=dict)


def _desired_speeds(
    frames: int, fps: float, rng: np.random.Generator, low: float, high: float, stops: bool
) -> np.ndarray:
    """(F,) the speed a driver wants at each frame: a new wish every 4–12 s, and with
    ``stops`` a halt of 3–8 s now and then (lights, queues)."""
    wish = np.empty(frames)
    frame = 0
    while frame < frames:
        halt = stops and frame > 0 and rng.uniform() < 0.12
        span = int(rng.uniform(3, 8) * fps) if halt else int(rng.uniform(4, 12) * fps)
        wish[frame : frame + span] = 0.0 if halt else rng.uniform(low, high)
        frame += span
    return wish


def _drive(
    start_s: np.ndarray, lane: np.ndarray, direction: np.ndarray, wish: np.ndarray, fps: float
) -> np.ndarray:
    """(F, A) positions of cars driving their lanes by the Intelligent Driver Model, each
    following the nearest car ahead in its lane (``wish``: (F, A) wanted speeds)."""
    frames, count = wish.shape
    steps = int(round(1 / (fps * SIM_DT_S)))
    dt = 1 / (fps * steps)
    a_max, b_comfort, headway_s, jam_m, car_m = 1.6, 2.5, 1.3, 2.5, 5.0
    u = start_s * direction  # position along each car's own direction
    v = wish[0].copy()
    group = lane * 2 + (direction > 0)
    out = np.empty((frames, count))
    for frame in range(frames):
        out[frame] = u * direction
        for _ in range(steps):
            order = np.lexsort((u, group))
            ahead = np.full(count, -1)
            same = group[order][1:] == group[order][:-1]
            ahead[order[:-1][same]] = order[1:][same]
            gap = np.where(ahead >= 0, u[np.maximum(ahead, 0)] - u - car_m, np.inf)
            closing = np.where(ahead >= 0, v - v[np.maximum(ahead, 0)], 0.0)
            wanted = jam_m + np.maximum(
                0.0, v * headway_s + v * closing / (2 * np.sqrt(a_max * b_comfort))
            )
            free = 1 - (v / np.maximum(wish[frame], 0.1)) ** 4
            accel = a_max * (
                np.where(wish[frame] > 0.1, free, -1.0) - (wanted / np.maximum(gap, 0.5)) ** 2
            )
            accel = np.clip(accel, -8.0, a_max)
            v = np.maximum(v + accel * dt, 0.0)
            u = u + v * dt
    return out


def _ribbon(
    road: Road,
    s0: float,
    s1: float,
    d: tuple[float, float],
    z: tuple[float, float],
    kind: str,
    spacing: float = 2.0,
) -> Mesh:
    """A strip along the road between offsets d[0] and d[1], at heights z[0], z[1] above the
    ground (a vertical strip when the offsets are equal)."""
    s = np.arange(s0, s1 + spacing, spacing)
    inner, ground, _ = road.pose(s, np.full_like(s, d[0]))
    outer, _, _ = road.pose(s, np.full_like(s, d[1]))
    left = np.column_stack([inner, ground + z[0]])
    right = np.column_stack([outer, ground + z[1]])
    sections = np.stack([left, right], axis=1)  # (S, 2, 3)
    count = len(s)
    index = np.arange(count * 2).reshape(count, 2)
    a, b, c, e = index[:-1, 0], index[:-1, 1], index[1:, 0], index[1:, 1]
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([b, e, c])])
    return Mesh(
        sections.reshape(-1, 3),
        triangles.astype(np.int32),
        np.full(len(triangles), meshes.material(kind)),
    )


def _placed(mesh: Mesh, road: Road, s: float, d: float, yaw_offset: float, lift: float) -> Mesh:
    xy, z, heading = road.pose(np.array([s]), np.array([d]))
    return mesh.placed(placements(xy, z, heading + yaw_offset, np.zeros(1), lift)[0])


def _roadside(
    road: Road, length: float, lots: dict[int, list[tuple[float, float]]], rng: np.random.Generator
) -> list[Mesh]:
    """Road, markings, kerbs, pavements, terrain and what stands beyond the kerbs."""
    parts = []
    right, left = -road.edge(-1), road.edge(1)
    parts.append(_ribbon(road, 0, length, (right, left), (0, 0), "road"))
    # dashed lane lines, the centre line, and the bike lanes' solid lines: 12 cm wide, 1 cm up
    for lane_line in range(-road.lanes + 1, road.lanes):
        d = lane_line * LANE_WIDTH_M
        dash_on, dash_off = (3.0, 6.0) if lane_line else (6.0, 3.0)
        for start in np.arange(rng.uniform(0, 9), length, dash_on + dash_off):
            parts.append(
                _ribbon(
                    road, start, start + dash_on, (d - 0.06, d + 0.06), (0.01, 0.01), "marking", 1.0
                )
            )
    for side in (-1, 1):
        d = side * road.lanes * LANE_WIDTH_M
        parts.append(_ribbon(road, 0, length, (d - 0.08, d + 0.08), (0.01, 0.01), "marking"))
    for side, edge in ((-1, right), (1, left)):
        if road.rural:
            parts.extend(
                _rural_edge(road, length, side, abs(edge), road.barriers[0 if side < 0 else 1], rng)
            )
            continue
        pavement = road.pavement_m[0 if side < 0 else 1]
        parts.append(_ribbon(road, 0, length, (edge, edge), (0.0, KERB_M), "kerb"))
        parts.append(
            _ribbon(road, 0, length, (edge, edge + side * pavement), (KERB_M, KERB_M), "sidewalk")
        )
        parts.append(
            _ribbon(
                road,
                0,
                length,
                (edge + side * pavement, side * 55.0),
                (KERB_M, KERB_M),
                "terrain",
                4.0,
            )
        )
        parts.extend(_beyond(road, length, side, abs(edge) + pavement, lots[side], rng))
    return parts


def _rural_edge(
    road: Road, length: float, side: int, edge_m: float, barrier: str, rng: np.random.Generator
) -> list[Mesh]:
    """A rural road's edge: a verge of grass, then a guard rail (a steel band on posts), a
    concrete barrier or nothing, and beyond it fields, hedges, woods and embankments."""
    verge = rng.uniform(0.3, 2.5)
    parts = [_ribbon(road, 0, length, (side * edge_m, side * 55.0), (0.0, 0.0), "terrain", 4.0)]
    at = side * (edge_m + verge)
    if barrier == "guardrail":
        parts.append(_ribbon(road, 0, length, (at, at), (0.45, 0.75), "metal"))
        post = meshes.box(0.12, 0.12, 0.75, "metal")
        parts += [
            _placed(post, road, s, at + side * 0.1, 0.0, 0.0)
            for s in np.arange(rng.uniform(0, 2), length, rng.uniform(2.0, 4.0))
        ]
    elif barrier == "concrete":
        parts.append(_ribbon(road, 0, length, (at, at), (0.0, rng.uniform(0.8, 1.1)), "wall"))
    parts.extend(_beyond(road, length, side, edge_m + verge + 0.5, [], rng, urban=False))
    return parts


def _free(s0: float, s1: float, taken: list[tuple[float, float]]) -> bool:
    return all(s1 <= a or s0 >= b for a, b in taken)


def _beyond(
    road: Road,
    length: float,
    side: int,
    start_d: float,
    lots: list[tuple[float, float]],
    rng: np.random.Generator,
    *,
    urban: bool | None = None,
) -> list[Mesh]:
    """What stands beyond a pavement: buildings with gaps (in town), hedges, fences,
    stretches of woodland and embankments (outside the parking ``lots``); trees, poles,
    bushes, bins and bollards along the kerb."""
    parts = []
    s = rng.uniform(-10, 5)
    urban = rng.uniform() < 0.6 if urban is None else urban
    while s < length:
        span = rng.uniform(8, 40)
        setback = rng.uniform(0.0, 5.0)
        roll = rng.uniform()
        if not _free(s, s + span, lots):
            pass
        elif urban and roll < 0.65:
            depth, height = rng.uniform(8, 15), rng.uniform(5, 18)
            building = meshes.box(span, depth, height, "wall")
            parts.append(
                _placed(
                    building,
                    road,
                    s + span / 2,
                    side * (start_d + setback + depth / 2),
                    0.0,
                    KERB_M,
                )
            )
        elif roll < 0.72:
            hedge = meshes.box(span, rng.uniform(0.6, 1.2), rng.uniform(0.8, 2.0), "foliage")
            parts.append(
                _placed(hedge, road, s + span / 2, side * (start_d + setback + 0.5), 0.0, KERB_M)
            )
        elif roll < 0.78:
            fence = meshes.box(span, 0.05, rng.uniform(1.0, 1.8), "metal")
            parts.append(
                _placed(fence, road, s + span / 2, side * (start_d + setback), 0.0, KERB_M)
            )
        else:  # woodland: bushes and trees of every size, a few metres deep
            for _ in range(int(span * rng.uniform(0.3, 0.8))):
                at, off = s + rng.uniform(0, span), side * (start_d + rng.uniform(0.5, 12.0))
                plant = (
                    meshes.tree(rng)
                    if rng.uniform() < 0.35
                    else meshes.blob(rng.uniform(0.3, 1.6), rng, "foliage", 0.35)
                )
                parts.append(_placed(plant, road, at, off, 0.0, KERB_M))
        if rng.uniform() < 0.15 and _free(s, s + span, lots):  # an embankment rising away
            rise = rng.uniform(1.0, 4.0)
            parts.append(
                _ribbon(
                    road,
                    s,
                    s + span,
                    (side * (start_d + setback + 1.0), side * (start_d + setback + 14.0)),
                    (KERB_M, KERB_M + rise),
                    "terrain",
                )
            )
        s += span + rng.uniform(2, 15)
    kerb = start_d - 0.4
    for at in np.arange(rng.uniform(0, 15), length, 1.0):
        roll = rng.uniform()
        if roll < 0.035:
            parts.append(
                _placed(
                    meshes.tree(rng), road, at, side * (kerb - rng.uniform(0.2, 1.0)), 0.0, KERB_M
                )
            )
        elif roll < 0.06:
            pole = meshes.cylinder(rng.uniform(0.05, 0.14), rng.uniform(2.5, 8.0), "metal", 8)
            parts.append(
                _placed(pole, road, at, side * (kerb + rng.uniform(-0.3, 0.3)), 0.0, KERB_M)
            )
        elif roll < 0.075:
            bush = meshes.blob(rng.uniform(0.4, 1.1), rng, "foliage", 0.3)
            parts.append(
                _placed(bush, road, at, side * (start_d + rng.uniform(0.5, 3.0)), 0.0, KERB_M)
            )
        elif roll < 0.085:
            bin_ = meshes.box(
                rng.uniform(0.5, 1.2), rng.uniform(0.5, 0.8), rng.uniform(0.9, 1.4), "wall"
            )
            parts.append(
                _placed(
                    bin_, road, at, side * (kerb - rng.uniform(0.0, 1.5)), rng.uniform(0, 3), KERB_M
                )
            )
        elif roll < 0.12:
            bollard = meshes.cylinder(0.08, rng.uniform(0.6, 1.0), "metal", 6)
            parts.append(_placed(bollard, road, at, side * (kerb + 0.2), 0.0, KERB_M))
    return parts


def _lots(
    road: Road, length: float, rng: np.random.Generator
) -> dict[int, list[tuple[float, float]]]:
    """Stretches (s0, s1) of each side where a car park lies beyond the pavement."""
    lots: dict[int, list[tuple[float, float]]] = {-1: [], 1: []}
    for side in (-1, 1):
        s = rng.uniform(0, 80)
        while s < length:
            if rng.uniform() < 0.25:
                span = rng.uniform(15, 50)
                lots[side].append((s, s + span))
                s += span
            s += rng.uniform(40, 120)
    return lots


def _vehicle(
    rng: np.random.Generator, shape: str | None = None, trucks: float = 0.0
) -> tuple[str, str, Mesh]:
    """A random vehicle: KITTI's type, its shape and mesh (a lorry with chance ``trucks``)."""
    if shape is None and rng.uniform() < trucks:
        return "Truck", "truck", meshes.truck(rng)
    shape, mesh = meshes.random_car(rng, shape)
    return ("Van" if shape == "van" else "Car"), shape, mesh


def random_street(frames: int, cars: int, rng: np.random.Generator, fps: float = 10.0) -> Street:
    """A street and ``cars`` moving cars (the first leads the ego car, in its lane, for the
    whole drive) for ``frames`` frames, with parked cars, pedestrians and cyclists."""
    if cars < 1:
        raise ValueError("a drive needs at least the one car the ego car follows (cars ≥ 1)")
    duration = frames / fps
    length = 120 + 16.0 * duration + 150
    road = random_road(length, rng)
    ego_lane = int(rng.integers(0, road.lanes))
    ego_start = 60.0
    # the ego car, the car it follows, then the others (same way or oncoming)
    lanes = [ego_lane, ego_lane]
    directions = [1, 1]
    starts = [ego_start, ego_start + rng.uniform(10, 25)]
    for _ in range(cars - 1):
        direction = int(rng.choice([1, -1], p=[0.6, 0.4]))
        lanes.append(int(rng.integers(0, road.lanes)))
        directions.append(direction)
        starts.append(
            rng.uniform(ego_start - 40, ego_start + 150)
            if direction > 0
            else rng.uniform(ego_start + 60, ego_start + 60 + 14 * duration)
        )
    lanes_arr, directions_arr = np.array(lanes), np.array(directions)
    starts_arr = _spread(np.array(starts), lanes_arr * 2 + (directions_arr > 0), keep=2)
    wish = np.column_stack(
        [
            _desired_speeds(frames, fps, rng, 6, 14, stops=False)
        ]  # the ego car: as fast as the lead lets it
        + [_desired_speeds(frames, fps, rng, 5, 13, stops=True)]
        + [
            _desired_speeds(frames, fps, rng, 5, 14, stops=rng.uniform() < 0.4)
            for _ in range(cars - 1)
        ]
    )
    positions = _drive(starts_arr, lanes_arr, directions_arr, wish, fps)
    agents = []
    for k in range(1, cars + 1):
        # the car the ego car follows is a car (KITTI's Car), not a van
        kind, shape, mesh = _vehicle(
            rng, str(rng.choice(meshes.CAR_SHAPES[:3])) if k == 1 else None
        )
        d = road.lane_offset(lanes[k], directions[k]) + rng.uniform(-0.3, 0.3)
        swerve = np.full(frames, d)
        agents.append(Agent(kind, mesh, positions[:, k], swerve, directions[k], shape=shape))
    moving = [True] * len(agents)
    lots = {-1: [], 1: []} if road.rural else _lots(road, length, rng)
    agents_static = _parked(road, length, lots, rng)
    agents += agents_static
    moving += [False] * len(agents_static)
    walkers = _walkers(road, length, frames, fps, rng)
    agents += walkers
    moving += [True] * len(walkers)
    ego_d = road.lane_offset(ego_lane, 1)
    return Street(
        road,
        _roadside(road, length, lots, rng),
        agents,
        positions[:, 0],
        ego_d,
        np.array(moving),
        notes={
            "lanes": road.lanes,
            "length_m": round(length, 1),
            "edges": list(road.barriers) if road.rural else "urban",
        },
    )


def _spread(starts: np.ndarray, group: np.ndarray, keep: int) -> np.ndarray:
    """Starting positions moved apart so no two cars of one lane begin within 9 m (the first
    ``keep`` stay where they are)."""
    out = starts.copy()
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        fixed = [m for m in members if m < keep]
        taken = list(out[fixed])
        for m in members:
            if m < keep:
                continue
            while any(abs(out[m] - t) < 9.0 for t in taken):
                out[m] += 9.0
            taken.append(out[m])
    return out


def _parked(
    road: Road, length: float, lots: dict[int, list[tuple[float, float]]], rng: np.random.Generator
) -> list[Agent]:
    """Cars parked along the parking lanes, and side by side in the car parks."""
    agents = []
    for side, index in ((-1, 0), (1, 1)):
        if road.parking[index]:
            d = side * (road.edge(side) - PARKING_M / 2)
            s = rng.uniform(0, 8)
            while s < length - 5:
                if rng.uniform() < 0.7:
                    kind, shape, mesh = _vehicle(rng)
                    facing = 1 if side < 0 or rng.uniform() < 0.3 else -1
                    at = np.full(1, s + mesh.box_size[0] / 2)
                    offset = np.full(1, d + rng.uniform(-0.15, 0.15))
                    agents.append(Agent(kind, mesh, at, offset, facing, shape=shape))
                    s += mesh.box_size[0] + rng.uniform(0.8, 2.5)
                else:
                    s += rng.uniform(5, 12)
        outer = road.edge(side) + road.pavement_m[index]
        for s0, s1 in lots[side]:
            for row in range(int(rng.integers(1, 3))):
                d = side * (outer + 3.0 + row * 5.5)
                for at in np.arange(s0 + 1.5, s1 - 1.5, rng.uniform(2.5, 3.0)):
                    if rng.uniform() < 0.35:
                        continue
                    kind, shape, mesh = _vehicle(rng)
                    turn = float(rng.choice([-1, 1]) * np.pi / 2 + rng.normal(0, 0.05))
                    agents.append(
                        Agent(
                            kind,
                            mesh,
                            np.full(1, at),
                            np.full(1, d),
                            1,
                            lift_m=KERB_M,
                            shape=shape,
                            yaw_offset=turn,
                        )
                    )
    return agents


def _walkers(
    road: Road, length: float, frames: int, fps: float, rng: np.random.Generator
) -> list[Agent]:
    """Pedestrians on the pavements or a rural road's verges (some standing) and cyclists
    in the bike lanes."""
    time = np.arange(frames) / fps
    agents = []
    for _ in range(int(length / (60 if road.rural else 25))):
        side = int(rng.choice([-1, 1]))
        pavement = road.pavement_m[0 if side < 0 else 1] if not road.rural else 1.2
        d = side * (road.edge(side) + rng.uniform(0.3, pavement - 0.3))
        direction = int(rng.choice([-1, 1]))
        speed = 0.0 if rng.uniform() < 0.25 else rng.uniform(0.9, 1.7)
        s = rng.uniform(0, length) + direction * speed * time
        agents.append(
            Agent(
                "Pedestrian",
                meshes.pedestrian(rng),
                s,
                np.full(frames, d),
                direction,
                lift_m=0.0 if road.rural else KERB_M,
            )
        )
    for _ in range(int(length / 120)):
        side = int(rng.choice([-1, 1]))
        d = side * (road.lanes * LANE_WIDTH_M + BIKE_LANE_M / 2)
        direction = -side
        s = rng.uniform(0, length) + direction * rng.uniform(3.5, 6.5) * time
        agents.append(Agent("Cyclist", meshes.cyclist(rng), s, np.full(frames, d), direction))
    return agents
