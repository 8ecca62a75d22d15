"""A differential-drive robot's motion: speed and turn-rate commands, followed within the
robot's acceleration limits, integrated finely; the floor camera rides ahead of the axle.

Paths: ``loop`` (the thesis-like closed circuit of 28.578 m), ``lawnmower`` (rows joined by
turns on the spot) and ``random`` (speeds up to 2 m/s, turn rates up to 180°/s, stops and
spins).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.odometry import se2

TIME_STEP_S = 1e-3
THESIS_PATH_MM = 28_578.3
PATHS = ("loop", "lawnmower", "random")


@dataclass(frozen=True)
class Command:
    """Hold a speed (mm/s, forward) and a turn rate (°/s, counter-clockwise seen from the
    camera, i.e. about z into the floor) for ``seconds``."""

    seconds: float
    speed_mm_s: float
    turn_deg_s: float = 0.0


@dataclass(frozen=True)
class Robot:
    accel_mm_s2: float = 1500.0
    turn_accel_deg_s2: float = 720.0
    camera_ahead_mm: float = 120.0
    """The camera's distance ahead of the axle's midpoint: a turn on the spot moves it
    sideways."""


@dataclass(frozen=True)
class Motion:
    """The camera's pose on the floor every ``TIME_STEP_S`` (x_mm, y_mm, θ_rad in the floor
    frame, x along the robot's heading at the start)."""

    t_s: np.ndarray
    pose: np.ndarray

    @property
    def seconds(self) -> float:
        return float(self.t_s[-1])

    @property
    def distance_mm(self) -> float:
        return float(np.hypot(*np.diff(self.pose[:, :2], axis=0).T).sum())

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """(…, 3) poses at any times in [0, seconds] (linear between the fine steps)."""
        t = np.clip(np.asarray(t_s, float), 0.0, self.seconds)
        x = np.interp(t, self.t_s, self.pose[:, 0])
        y = np.interp(t, self.t_s, self.pose[:, 1])
        theta = np.interp(t, self.t_s, np.unwrap(self.pose[:, 2]))
        return np.stack([x, y, se2.wrap(theta)], axis=-1)


def _profile(values: np.ndarray, starts: np.ndarray, end: float, rate: float) -> tuple:
    """Knots of a piecewise-linear profile that moves to each commanded value at ``rate``
    from its command's start (cut short by the next command)."""
    times, levels = [0.0], [0.0]
    for k, (start, value) in enumerate(zip(starts, values, strict=True)):
        stop = starts[k + 1] if k + 1 < len(starts) else end
        level = levels[-1]
        ramp = abs(value - level) / rate
        reach = min(ramp, stop - start)
        reached = level + (value - level) * (reach / ramp if ramp > 0 else 1.0)
        times += [start, start + reach]
        levels += [level, reached]
    times.append(end)
    levels.append(levels[-1])
    return np.array(times), np.array(levels)


def drive(commands: list[Command], robot: Robot = Robot()) -> Motion:
    """The camera's motion under ``commands``, from rest at the origin."""
    durations = np.array([c.seconds for c in commands])
    starts = np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    end = float(durations.sum())
    t = np.arange(0.0, end + TIME_STEP_S / 2, TIME_STEP_S)
    speed = np.interp(
        t,
        *_profile(np.array([c.speed_mm_s for c in commands]), starts, end, robot.accel_mm_s2),
    )
    turn = np.radians(
        np.interp(
            t,
            *_profile(
                np.array([c.turn_deg_s for c in commands]), starts, end, robot.turn_accel_deg_s2
            ),
        )
    )
    # trapezoidal running sums of the rates
    heading = np.concatenate([[0.0], np.cumsum((turn[1:] + turn[:-1]) / 2 * TIME_STEP_S)])
    mid_heading = np.concatenate([[0.0], (heading[1:] + heading[:-1]) / 2])
    mid_speed = np.concatenate([[0.0], (speed[1:] + speed[:-1]) / 2])
    x = np.cumsum(mid_speed * np.cos(mid_heading) * TIME_STEP_S)
    y = np.cumsum(mid_speed * np.sin(mid_heading) * TIME_STEP_S)
    axle = np.column_stack([x, y, heading])
    camera = se2.compose(axle, np.array([robot.camera_ahead_mm, 0.0, 0.0]))
    origin = se2.inverse(camera[0])
    return Motion(t, se2.compose(origin, camera))


def loop_path(cruise_mm_s: float = 600.0, turn_deg_s: float = 45.0) -> list[Command]:
    """A closed circuit like the thesis's (Figure 6.10): straights, rounded corners, an
    S-bend, a stop and a turn on the spot, stretched to 28.578 m of camera travel."""
    corner = Command(90 / turn_deg_s, cruise_mm_s, turn_deg_s)
    commands = [
        Command(6.0, cruise_mm_s),
        corner,
        Command(3.0, cruise_mm_s),
        Command(45 / turn_deg_s, cruise_mm_s, -turn_deg_s),
        Command(45 / turn_deg_s, cruise_mm_s, turn_deg_s),
        corner,
        Command(6.0, cruise_mm_s),
        Command(1.0, 0.0),
        Command(90 / turn_deg_s, 0.0, turn_deg_s),
        Command(3.0, cruise_mm_s),
        corner,
        Command(4.0, cruise_mm_s),
    ]
    return _stretched(commands, THESIS_PATH_MM, cruise_mm_s)


def lawnmower_path(rows: int = 4, row_mm: float = 3000.0, pitch_mm: float = 150.0) -> list:
    """Rows ``pitch_mm`` apart joined by stops and 90° turns on the spot."""
    speed, spin = 800.0, 90.0
    commands = []
    for row in range(rows):
        side = 1 if row % 2 == 0 else -1
        commands += [Command(row_mm / speed, speed), Command(0.5, 0.0)]
        commands += [Command(1.0, 0.0, side * spin), Command(pitch_mm / 300.0, 300.0)]
        commands += [Command(1.0, 0.0, side * spin), Command(0.5, 0.0)]
    return commands


def random_path(seconds: float, rng: np.random.Generator) -> list[Command]:
    """Commands of 0.3–2 s: speeds up to 2 m/s, turn rates up to 180°/s, stops and spins."""
    commands, total = [], 0.0
    while total < seconds:
        duration = float(rng.uniform(0.3, 2.0))
        kind = rng.choice(["drive", "drive", "drive", "stop", "spin"])
        if kind == "stop":
            command = Command(duration, 0.0)
        elif kind == "spin":
            command = Command(duration, 0.0, float(rng.choice([-1, 1]) * rng.uniform(30, 180)))
        else:
            command = Command(duration, float(rng.uniform(100, 2000)), float(rng.uniform(-90, 90)))
        commands.append(command)
        total += duration
    return commands


def path_commands(name: str, *, seconds: float | None, seed: int) -> list[Command]:
    """The named path, cut to ``seconds`` (None: the path's own length)."""
    if name == "loop":
        commands = loop_path()
    elif name == "lawnmower":
        commands = lawnmower_path()
    elif name == "random":
        commands = random_path(seconds or 20.0, np.random.default_rng(seed))
    else:
        raise ValueError(f"unknown path {name!r}; known: {', '.join(PATHS)}")
    return commands if seconds is None else _cut(commands, seconds)


def _cut(commands: list[Command], seconds: float) -> list[Command]:
    out, total = [], 0.0
    for command in commands:
        if total >= seconds:
            break
        take = min(command.seconds, seconds - total)
        out.append(Command(take, command.speed_mm_s, command.turn_deg_s))
        total += take
    if total < seconds:  # repeat the path until the time is filled
        out += _cut(commands, seconds - total)
    return out


def _stretched(commands: list[Command], length_mm: float, cruise_mm_s: float) -> list[Command]:
    """``commands`` with the first straight lengthened or shortened so that the camera
    travels ``length_mm``."""
    travelled = drive(commands).distance_mm
    first = commands[0]
    seconds = first.seconds + (length_mm - travelled) / cruise_mm_s
    if seconds <= 0:
        raise ValueError("the path is longer than asked without its first straight")
    return [Command(seconds, first.speed_mm_s, first.turn_deg_s), *commands[1:]]
