"""Simulated robot–sensor calibration sessions with known ``flange_T_sensor``.

A plate with two reference holes lies in the robot's workspace; the robot shows it to the
sensor from ``poses`` viewpoints (standoff, tilt and roll varied, as a person teaching a
calibration would). At each pose the robot reports ``base_T_flange`` with its
repeatability error and the sensor reports ``sensor_T_target`` with its own noise (by
default the calibration's, ``kinds.NoiseModel``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.lib.pointcloud.transforms import from_rotvec, invert, look_at, perturb
from services.stitching.kinds import NoiseModel

NOISE = NoiseModel()
STANDOFF_MM = (190.0, 250.0)
"""Gocator 3210: clearance 164 mm plus its 110 mm measuring range; the plate in the middle."""
MAX_TILT_DEG = 30.0


@dataclass(frozen=True)
class CalibrationSession:
    """(k, 4, 4) arrays of what was reported, and the truth they came from."""

    base_T_flange: np.ndarray
    sensor_T_target: np.ndarray
    true_flange_T_sensor: np.ndarray
    true_base_T_target: np.ndarray
    true_base_T_flange: np.ndarray
    corrupted: tuple[int, ...] = ()
    """Indices of pairs whose plate pose was made wrong on purpose (a mis-detected hole)."""


def nominal_flange_T_sensor(rng: np.random.Generator) -> np.ndarray:
    """A sensor bracket: ~120 mm out along the tool axis, offset, turned a quarter turn and
    a few degrees off square, as a real mount is."""
    rotvec = np.radians([0.0, 0.0, 90.0] + rng.normal(0.0, 3.0, 3))
    translation = np.array([35.0, -60.0, 120.0]) + rng.normal(0.0, 5.0, 3)
    return from_rotvec(rotvec, translation)


def simulate_calibration(
    *,
    poses: int = 15,
    robot_sigma_mm: float = NOISE.robot_sigma_mm,
    robot_sigma_deg: float = NOISE.robot_sigma_deg,
    sensor_sigma_mm: float = NOISE.sensor_sigma_mm,
    sensor_sigma_deg: float = NOISE.sensor_sigma_deg,
    corrupt: int = 0,
    corrupt_mm: float = 2.0,
    corrupt_deg: float = 1.0,
    rng: np.random.Generator,
) -> CalibrationSession:
    """One calibration session; ``corrupt`` pairs get a plate pose off by ``corrupt_mm`` and
    ``corrupt_deg`` (random directions)."""
    if poses < 3:
        raise ValueError("a calibration needs at least 3 poses")
    flange_T_sensor = nominal_flange_T_sensor(rng)
    base_T_target = from_rotvec(
        np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)]),
        np.array([650.0, 150.0, -250.0]) + rng.normal(0.0, 20.0, 3),
    )
    plate_centre = base_T_target[:3, 3]
    base_T_sensor = np.empty((poses, 4, 4))
    for i in range(poses):
        tilt = np.radians(rng.uniform(5.0, MAX_TILT_DEG))
        azimuth = rng.uniform(0.0, 2 * np.pi)
        direction = np.array(
            [np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)]
        )
        eye = plate_centre + rng.uniform(*STANDOFF_MM) * direction
        aim = plate_centre + np.append(rng.normal(0.0, 10.0, 2), 0.0)
        roll = rng.uniform(-np.pi, np.pi)
        up = np.array([np.cos(roll), np.sin(roll), 0.0])
        base_T_sensor[i] = look_at(eye, aim, up)
    true_base_T_flange = base_T_sensor @ invert(flange_T_sensor)
    true_sensor_T_target = invert(base_T_sensor) @ base_T_target
    reported_flange = perturb(true_base_T_flange, robot_sigma_mm, robot_sigma_deg, rng)
    measured_target = perturb(true_sensor_T_target, sensor_sigma_mm, sensor_sigma_deg, rng)
    corrupted = tuple(sorted(rng.choice(poses, size=corrupt, replace=False).tolist()))
    for index in corrupted:
        axis = _unit(rng.normal(size=3))
        shift = _unit(rng.normal(size=3)) * corrupt_mm
        measured_target[index] = measured_target[index] @ from_rotvec(
            axis * np.radians(corrupt_deg), shift
        )
    return CalibrationSession(
        base_T_flange=reported_flange,
        sensor_T_target=measured_target,
        true_flange_T_sensor=flange_T_sensor,
        true_base_T_target=base_T_target,
        true_base_T_flange=true_base_T_flange,
        corrupted=corrupted,
    )


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)
