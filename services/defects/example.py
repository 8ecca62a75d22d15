"""A simulated panel-assembly inspection on disk: what ``vista defects simulate`` writes.

pairs.json (calibration session), scan_NNN.ply (organized, coloured), scans.json (the
robot's reported poses), config.json (default tolerances), cloud.ply (the scans merged
at their true poses: what a perfect stitch gives) and truth.json (the true mount and
poses, and every seam, junction and defect of the assembly in the base frame).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.vocabulary import Say
from services.defects.config import MeasureConfig, config_document
from services.defects.simulate import (
    Assembly,
    AssemblyScans,
    AssemblySpec,
    assembly_mesh,
    random_assembly,
    scan_assembly,
)
from services.defects.truth import truth_of
from services.lib.pointcloud.mesh_distance import TriangleMesh
from services.lib.pointcloud.ply import PointCloud, write_ply
from services.lib.pointcloud.scan_sim import SensorModel
from services.lib.pointcloud.stl import write_stl
from services.lib.pointcloud.transforms import apply, invert, make_transform, perturb, to_json
from services.stitching.calibration_sim import simulate_calibration
from services.stitching.example import calibration_truth, write_session
from services.stitching.stitch import StitchConfig, stitch

BASE_T_PART = make_transform(np.eye(3), np.array([550.0, -100.0, -250.0]))
"""Where the assembly lies in front of the robot."""


@dataclass(frozen=True)
class DefectsExample:
    scans: int
    panels: int
    seams: int
    junctions: int
    defects: int
    cloud_points: int


def merged_cloud(
    scans: AssemblyScans, voxel_mm: float, *, misregistration_mm: float = 0.0
) -> PointCloud:
    """The scans merged at their true poses (cleaned, closest-vertex merge): a perfect
    stitch — or, with ``misregistration_mm``, every other scan shifted that far along the
    base x axis (across the seams that run along the layout's s)."""
    clouds = [
        PointCloud(points=g.reshape(-1, 3), colors=c.reshape(-1, 3), grid_shape=g.shape[:2])
        for g, c in zip(scans.scans, scans.colors, strict=True)
    ]
    poses = scans.base_T_sensor.copy()
    poses[1::2, 0, 3] += misregistration_mm
    return stitch(clouds, poses, np.eye(4), config=StitchConfig(voxel_mm=voxel_mm)).cloud


def write_defects_example(
    out_dir: Path,
    spec: AssemblySpec,
    *,
    grid: tuple[int, int] = (1000, 1540),
    poses: int = 15,
    voxel_mm: float = 0.1,
    seed: int = 0,
    progress: Say | None = None,
) -> DefectsExample:
    """Simulate an assembly, its calibration session and its scans, and write them with
    the ground truth. ``grid`` (1000, 1540) samples the 154 × 100 mm field every 0.1 mm."""
    say = progress or (lambda message: None)
    rng = np.random.default_rng(seed)
    assembly = random_assembly(spec, rng)
    session = simulate_calibration(poses=poses, rng=rng)
    sensor = SensorModel(grid=grid)
    say(f"scanning {len(assembly.panels)} panels at {grid[0]} × {grid[1]} per snapshot")
    scans = scan_assembly(assembly, BASE_T_PART, sensor, rng=rng)
    true_base_T_flange = scans.base_T_sensor @ invert(session.true_flange_T_sensor)
    reported = perturb(true_base_T_flange, 0.05, 0.005, rng)
    say(f"writing {len(scans.scans)} scans")
    write_session(out_dir, session, scans.scans, scans.colors, reported)
    say("merging the scans at their true poses into cloud.ply")
    merged = merged_cloud(scans, voxel_mm)
    write_ply(out_dir / "cloud.ply", merged, comments=("vista simulated assembly, base frame, mm",))
    truth = {
        **calibration_truth(session),
        "scan_true_base_T_flange": [to_json(t) for t in true_base_T_flange],
        "base_T_part": to_json(BASE_T_PART),
        "sensor": {"grid": list(grid), "noise_mm": sensor.noise_mm},
        "seed": seed,
        **truth_of(assembly, BASE_T_PART).document(),
    }
    (out_dir / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    write_assembly_nominal(out_dir / "nominal.stl", assembly)
    (out_dir / "config.json").write_text(
        json.dumps(config_document(MeasureConfig()), indent=1) + "\n"
    )
    return DefectsExample(
        len(scans.scans),
        len(assembly.panels),
        len(assembly.seams),
        len(assembly.junctions),
        len(truth["defects"]),
        len(merged.points),
    )


def write_assembly_nominal(path: Path, assembly: Assembly) -> None:
    """The assembly's nominal as an ASCII STL in the base frame (the merged cloud's): one
    solid per panel (``panel N``) and the backing; its dents, scratches and colour patches
    are what a comparison finds."""
    mesh, owner = assembly_mesh(assembly)
    names = tuple(f"panel {p.id}" for p in assembly.panels) + ("backing",)
    region = np.where(owner < 0, len(assembly.panels), owner)
    vertices = apply(BASE_T_PART, mesh.vertices)
    # the scan simulator's faces are wound the other way (its ray caster ignores which
    # side they face): a nominal's normals point out of the material
    faces = np.asarray(mesh.faces)[:, ::-1]
    write_stl(path, TriangleMesh(vertices, faces), binary=False, region_of_face=region,
              regions=names)  # fmt: skip


def write_demo_assembly(out_dir: Path, *, spacing_mm: float, seed: int, say: Say) -> DefectsExample:
    """`vista demo`'s data (the registry names it ``DEMO_EXAMPLE``): a curved cabin sidewall
    of 2 × 2 panels (R 2000 mm) whose seams stray out of tolerance, scanned every
    ``spacing_mm``, with its ground truth."""
    spec = AssemblySpec(
        rows=2,
        cols=2,
        panel_mm=(150.0, 100.0),
        radius_mm=2000.0,
        gap_mm=(0.8, 3.6),
        step_mm=(-1.2, 1.2),
        taper_mm=(0.0, 0.8),
    )
    say(f"simulating a curved cabin sidewall (2 × 2 panels, R 2000 mm) into {out_dir}")
    grid = (int(round(100 / spacing_mm)), int(round(154 / spacing_mm)))
    return write_defects_example(out_dir, spec, grid=grid, seed=seed, progress=say)
