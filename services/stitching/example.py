"""A complete simulated stitching example on disk: what ``vista stitching simulate`` writes
and the stitching benchmark stitches. pairs.json, scan_NNN.ply, scans.json, truth.json."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.lib.pointcloud import scan_sim
from services.lib.pointcloud.ply import PointCloud, write_ply
from services.lib.pointcloud.transforms import to_json
from services.stitching.calibration_sim import CalibrationSession, simulate_calibration
from services.stitching.files import write_pairs, write_scans
from services.stitching.kinds import NoiseModel


@dataclass(frozen=True)
class Example:
    scans: int
    component_name: str
    corrupted_pairs: tuple[int, ...]


def write_session(
    out_dir: Path,
    session: CalibrationSession,
    grids: list[np.ndarray],
    colors: list[np.ndarray] | None,
    base_T_flange: np.ndarray,
) -> list[str]:
    """pairs.json of the calibration session, scan_NNN.ply of each organized grid (with
    its colours) and scans.json with the robot's reported poses; the scans' names."""
    out_dir.mkdir(parents=True, exist_ok=True)
    write_pairs(out_dir / "pairs.json", session.base_T_flange, session.sensor_T_target)
    names = [f"scan_{i:03d}.ply" for i in range(len(grids))]
    for i, (name, grid) in enumerate(zip(names, grids, strict=True)):
        rgb = None if colors is None else colors[i].reshape(-1, 3)
        cloud = PointCloud(points=grid.reshape(-1, 3), colors=rgb, grid_shape=grid.shape[:2])
        write_ply(out_dir / name, cloud)
    write_scans(out_dir / "scans.json", names, base_T_flange)
    return names


def calibration_truth(session: CalibrationSession) -> dict:
    return {
        "flange_T_sensor": to_json(session.true_flange_T_sensor),
        "base_T_target": to_json(session.true_base_T_target),
        "calibration_true_base_T_flange": [to_json(t) for t in session.true_base_T_flange],
        "corrupted_pairs": list(session.corrupted),
    }


def write_example(
    out_dir: Path,
    *,
    component: str = "angle",
    poses: int = 15,
    corrupt: int = 0,
    grid: tuple[int, int] = (250, 385),
    seed: int = 0,
) -> Example:
    """Simulate a calibration session and the scans of ``component`` and write them, with
    the ground truth (true mount, true robot poses, the part's pose and bounding box). One
    robot and sensor, with the noise a calibration assumes by default, for both."""
    rng = np.random.default_rng(seed)
    noise = NoiseModel()
    session = simulate_calibration(poses=poses, **noise.model_dump(), corrupt=corrupt, rng=rng)
    mesh = scan_sim.COMPONENTS[component]()
    sensor = scan_sim.SensorModel(grid=grid)
    scans = scan_sim.simulate_scans(
        mesh,
        session.true_flange_T_sensor,
        sensor=sensor,
        robot_sigma_mm=noise.robot_sigma_mm,
        robot_sigma_deg=noise.robot_sigma_deg,
        rng=rng,
    )
    names = write_session(out_dir, session, scans.scans, None, scans.base_T_flange)
    corners = mesh.vertices @ scans.base_T_part[:3, :3].T + scans.base_T_part[:3, 3]
    truth = {
        **calibration_truth(session),
        "component": component,
        "component_name": mesh.name,
        "base_T_part": to_json(scans.base_T_part),
        "model_bounds_min_mm": corners.min(0).tolist(),
        "model_bounds_max_mm": corners.max(0).tolist(),
        "scan_true_base_T_flange": [to_json(t) for t in scans.true_base_T_flange],
        "sensor": {
            "grid": list(sensor.grid),
            "field_mm": list(sensor.field_mm),
            "standoff_mm": sensor.standoff_mm,
            "noise_mm": sensor.noise_mm,
        },
        "seed": seed,
    }
    (out_dir / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return Example(len(names), mesh.name, session.corrupted)
