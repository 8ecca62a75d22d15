"""``vista defects bench --sweep nominal``: the comparison with a nominal against the truth
and against the peers a plant engineer would otherwise use, in the same run.

1. **Distance**: a box (analytic distance) and a fuselage panel of ~200 000 triangles with
   a scan of ``points`` points; vista's signed distance beside CloudCompare's cloud-to-mesh
   distance (``CloudCompare -SILENT … -C2M_DIST``, Debian's 2.11, offscreen) and Open3D's
   ``RaycastingScene.compute_signed_distance``: the values compared point by point and the
   times side by side (vista and Open3D on ``threads`` threads; CloudCompare as it runs).
2. **Parts**: simulated parts (``services.defects.nominal_parts``: a skin panel warped
   0.1–1 mm and dented, an angle profile twisted, a plate with a mis-drilled hole), a fifth
   of each unscanned and 5 % of the points stray, the scan 3 mm and 2° away: the best
   fit's error against the true pose (on the same parts unwarped, as its target is stated),
   the deviation's error against the truth, and the findings' recall and false findings
   per m² against the true areas out of the band (each dent deeper than it, the hole's
   leftover material, a warp beyond it).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.tolerances import Tolerances, limits_of
from services.defects.align import best_fit, pose_difference
from services.defects.deviation import judge_deviation
from services.defects.nominal_parts import NominalPart, make_part
from services.lib.pointcloud.mesh_distance import TriangleMesh, index_mesh, signed_distance
from services.lib.pointcloud.ply import PointCloud, read_ply, write_ply
from services.lib.pointcloud.stl import write_stl
from services.lib.pointcloud.transforms import apply

BAND_MM = 0.25
"""The profile band (±) the sweep's parts are judged against."""
NOISE_MM = 0.01
"""The simulated scanner's noise (``make_part``'s default)."""
DISTANCE_POINTS = 10_000_000
PANEL_TRIANGLES = 200_000
TARGETS = {
    "nominal: signed distance error against the analytic box (mm)": 0.001,
    "nominal: largest difference from CloudCompare's C2M where both answer (mm)": 0.001,
    "nominal: times faster than CloudCompare's C2M": 2.0,
    "nominal: times faster than Open3D's RaycastingScene": 1.0,
    "nominal: best-fit error (mm)": 0.02,
    "nominal: best-fit error (degrees)": 0.005,
    "nominal: findings recall": 0.95,
    "nominal: false findings per m²": 1.0,
}


@dataclass(frozen=True)
class PartCase:
    name: str
    part: str
    warp_mm: float
    dents: int = 3


PART_CASES = (
    PartCase("panel warped 0.1 mm", "panel", 0.1),
    PartCase("panel warped 0.3 mm", "panel", 0.3),
    PartCase("panel warped 1.0 mm", "panel", 1.0),
    PartCase("angle twisted 0.3 mm", "angle", 0.3),
    PartCase("angle twisted 1.0 mm", "angle", 1.0),
    PartCase("plate, hole 6 mm off", "plate", 0.0),
)


def run_nominal_sweep(
    *, seeds: int, seed: int, threads: int, points: int = DISTANCE_POINTS
) -> dict:
    """Both parts of the sweep: their rows, printed tables and verdict."""
    distance = distance_rows(points, threads, seed)
    parts = [part_row(case, s, threads) for case in PART_CASES for s in range(seed, seed + seeds)]
    verdict = _verdict(distance, parts)
    print("\n## Signed distance to a nominal: vista and its peers on the same cloud and mesh\n")
    print(distance_table(distance))
    print(f"\n## Parts against their nominal ({seeds} per case; band ±{BAND_MM} mm)\n")
    print(parts_table(parts))
    return {"nominal_distance": distance, "nominal_parts": parts, "verdict": verdict}


def distance_rows(points: int, threads: int, seed: int) -> list[dict]:
    """The box against its analytic distance; the fine panel against both peers."""
    rng = np.random.default_rng(seed)
    half = np.array([40.0, 25.0, 10.0])
    box = _box(half)
    probe = rng.uniform(-80, 80, (200_000, 3))
    q = np.abs(probe) - half
    exact = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    found = signed_distance(box, probe, threads).distance_mm
    rows = [
        {
            "case": "box, 200 000 points (analytic)",
            "vista_error_max_mm": float(np.abs(found - exact).max()),
        }
    ]
    mesh, cloud = _fine_panel(points, rng)
    rows.append(_against_peers(mesh, cloud, threads))
    return rows


def _against_peers(mesh: TriangleMesh, cloud: np.ndarray, threads: int) -> dict:
    clock = time.perf_counter()
    index = index_mesh(mesh)
    indexed = time.perf_counter() - clock
    found = signed_distance(index, cloud, threads)
    vista_s = time.perf_counter() - clock
    row = {
        "case": f"panel, {len(cloud)} points vs {len(mesh.faces)} triangles",
        "vista_seconds": round(vista_s, 3),
        "vista_index_seconds": round(indexed, 3),
    }
    open3d = _open3d(mesh, cloud, threads)
    if open3d is not None:
        values, seconds = open3d
        difference = np.abs(values - found.distance_mm)
        row |= {
            "open3d_seconds": round(seconds, 3),
            "open3d_difference_p99_mm": float(np.percentile(difference, 99)),
            "open3d_difference_max_mm": float(difference.max()),
        }
    compare = _cloudcompare(mesh, cloud)
    if isinstance(compare, str):
        row["cloudcompare"] = compare
    else:
        values, seconds, compute = compare
        both = np.isfinite(values)
        difference = np.abs(values[both] - found.distance_mm[both])
        row |= {
            "cloudcompare_seconds": round(seconds, 3),
            "cloudcompare_compute_seconds": round(compute, 3),
            "cloudcompare_difference_p99_mm": float(np.percentile(difference, 99)),
            "cloudcompare_difference_max_mm": float(difference.max()),
            "cloudcompare_same_sign": float(np.mean(np.sign(values[both]) == np.sign(found.distance_mm[both]))),
        }  # fmt: skip
    return row


def _open3d(mesh: TriangleMesh, cloud: np.ndarray, threads: int) -> tuple[np.ndarray, float] | None:
    try:
        import open3d as o3d
    except ImportError:
        return None
    clock = time.perf_counter()
    scene = o3d.t.geometry.RaycastingScene(nthreads=threads)
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices_mm, np.float32)),
        o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)),
    )
    values = scene.compute_signed_distance(o3d.core.Tensor(cloud.astype(np.float32))).numpy()
    return values.astype(np.float64), time.perf_counter() - clock


def _cloudcompare(mesh: TriangleMesh, cloud: np.ndarray) -> tuple[np.ndarray, float, float] | str:
    """CloudCompare's C2M signed distances, its wall time (reading the files included,
    writing its result not) and the compute time it prints; or why there are none."""
    program = shutil.which("CloudCompare")
    if program is None:
        return "not installed (apt-get install cloudcompare)"
    with tempfile.TemporaryDirectory() as folder:
        base = Path(folder)
        write_ply(base / "cloud.ply", PointCloud(cloud.astype(np.float32)))
        write_stl(base / "mesh.stl", mesh)
        command = [program, "-SILENT", "-AUTO_SAVE", "OFF", "-C_EXPORT_FMT", "PLY",
                   "-O", str(base / "cloud.ply"), "-O", str(base / "mesh.stl"), "-C2M_DIST",
                   "-SAVE_CLOUDS", "FILE", str(base / "out.ply")]  # fmt: skip
        environment = {**os.environ, "QT_QPA_PLATFORM": "offscreen"}
        clock = time.perf_counter()
        done = subprocess.run(
            command, env=environment, capture_output=True, text=True, timeout=3600
        )
        seconds = time.perf_counter() - clock
        if done.returncode != 0 or not (base / "out.ply").exists():
            return f"failed: {(done.stdout + done.stderr)[-300:]}"
        compute = sum(float(t) for t in re.findall(r"Time: ([0-9.]+) s", done.stdout))
        result = read_ply(base / "out.ply")
        values = next(iter(result.extra.values())).astype(np.float64)
    if len(values) != len(cloud):
        return f"answered {len(values)} of {len(cloud)} points"
    return values, seconds, compute


def part_row(case: PartCase, seed: int, threads: int) -> dict:
    """One simulated part: the best fit (on it unwarped, and warped), the deviation and the
    findings against the truth."""
    limits = limits_of(Tolerances.model_validate({"profile_mm": {"max": BAND_MM}}))
    made = make_part(case.part, seed=seed, spacing_mm=0.5, warp_mm=case.warp_mm, dents=case.dents)
    flat = make_part(case.part, seed=seed, spacing_mm=0.5, warp_mm=0.0, dents=case.dents)
    index = index_mesh(made.mesh)
    vertices = np.asarray(made.mesh.vertices_mm)
    clock = time.perf_counter()
    fit = best_fit(index, flat.points_mm, np.eye(4), workers=threads)
    fit_seconds = time.perf_counter() - clock
    fit_mm, fit_deg = pose_difference(fit.nominal_T_cloud, flat.nominal_T_cloud, vertices)
    warped_fit = best_fit(index, made.points_mm, np.eye(4), workers=threads)
    warped_mm, warped_deg = pose_difference(
        warped_fit.nominal_T_cloud, made.nominal_T_cloud, vertices
    )
    aligned = apply(made.nominal_T_cloud, made.points_mm)  # the cell's pose: given
    found = signed_distance(index, aligned, threads)
    known = np.isfinite(made.deviation_mm)
    error = np.abs(found.distance_mm[known] - made.deviation_mm[known])
    deviation = judge_deviation(aligned, found, made.mesh, made.region_of_face, made.regions,
                                limits, sigma_mm=fit.residual_robust_mm)  # fmt: skip
    out = [f for f in deviation.findings if f.state != "within"]
    # recall over the areas out by 2σ or more (nearer the band the noise may decide);
    # a finding is false where the part is not out of the band at all
    truth = _true_areas(made, aligned, deviation.spacing_mm, 2 * NOISE_MM)
    real = _true_areas(made, aligned, deviation.spacing_mm, 0.0)
    matched = {i for i, area in enumerate(truth) for f in out if _inside(f, area)}
    false = [f for f in out if not any(_inside(f, area) for area in real)]
    area_m2 = _scanned_area_m2(made, deviation)
    return {
        "case": case.name,
        "seed": seed,
        "points": len(made.points_mm),
        "fit_error_mm": fit_mm,
        "fit_error_deg": fit_deg,
        "fit_seconds": round(fit_seconds, 3),
        "fit_warnings": list(fit.warnings),
        "warped_fit_error_mm": warped_mm,
        "warped_fit_error_deg": warped_deg,
        "deviation_error_p95_mm": float(np.percentile(error, 95)),
        "noise_mm": NOISE_MM,
        "true_areas": len(truth),
        "found": len(out),
        "matched": len(matched),
        "false": len(false),
        "scanned_m2": area_m2,
    }


def _true_areas(
    part: NominalPart, aligned: np.ndarray, spacing: float, margin_mm: float
) -> list[tuple[np.ndarray, float]]:
    """Where the part is truly out of the band by more than ``margin_mm``, as (centre,
    radius): the connected areas of points whose true deviation is (clustered as the
    findings are), and the hole's leftover material."""
    from services.defects.deviation import connected_areas

    true = part.deviation_mm
    beyond = np.isfinite(true) & (np.abs(true) > BAND_MM + margin_mm)
    region = np.zeros(len(true), dtype=np.int64)
    areas = []
    for side in (beyond & (true > 0), beyond & (true < 0)):
        for members in connected_areas(aligned, side, region, spacing):
            low, high = aligned[members].min(axis=0), aligned[members].max(axis=0)
            areas.append(((low + high) / 2, float(np.linalg.norm(high - low)) / 2))
    if part.hole is not None:
        areas.append((np.array([-4.0, 0.0, 0.0]), 10.0))
    return areas


def _inside(finding, area: tuple[np.ndarray, float]) -> bool:  # noqa: ANN001
    centre, radius = area
    return float(np.linalg.norm(finding.at_mm - centre)) < radius + finding.extent_mm / 2


def _scanned_area_m2(part: NominalPart, deviation) -> float:  # noqa: ANN001
    corners = np.asarray(part.mesh.vertices_mm)[part.mesh.faces]
    area = 0.5 * np.linalg.norm(
        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
    )
    per_region = np.bincount(part.region_of_face, weights=area, minlength=len(part.regions))
    covered = np.array([r.coverage_share for r in deviation.regions])
    return float((per_region * covered).sum() / 1e6)


def _fine_panel(points: int, rng: np.random.Generator) -> tuple[TriangleMesh, np.ndarray]:
    """A 600 × 400 mm skin panel (1 m radius) of about ``PANEL_TRIANGLES`` triangles, and a
    scan of it: ``points`` points in scan lines, 0.02 mm noise, three dents."""
    from services.defects.nominal_parts import grid_sheet

    radius = 1000.0
    columns = int(np.sqrt(PANEL_TRIANGLES / 2 * 1.5))
    rows = int(PANEL_TRIANGLES / 2 / columns)

    def xyz(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.column_stack(
            [radius * np.sin(u / radius), v, radius * np.cos(u / radius) - radius]
        )

    vertices, faces = grid_sheet(
        np.linspace(-300, 300, columns + 1), np.linspace(-200, 200, rows + 1), xyz
    )
    side = int(np.sqrt(points * 1.5))
    u, v = np.meshgrid(np.linspace(-299, 299, side), np.linspace(-199, 199, points // side))
    scan = xyz(u.ravel(), v.ravel())
    normals = scan - np.array([0.0, 0.0, -radius])
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    offset = rng.normal(0, 0.02, len(scan))
    for centre in ((-100.0, 50.0), (120.0, -80.0), (0.0, 0.0)):
        r = np.hypot(u.ravel() - centre[0], v.ravel() - centre[1])
        offset -= np.where(r < 10, 0.4 * (1 + np.cos(np.pi * r / 10)), 0.0)
    return TriangleMesh(vertices, faces), scan + offset[:, None] * normals


def _box(half: np.ndarray) -> TriangleMesh:
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])  # fmt: skip
    return TriangleMesh(corners * half, faces)


def _verdict(distance: list[dict], parts: list[dict]) -> dict[str, bool]:
    peers = distance[1]
    verdict = {
        "nominal: signed distance error against the analytic box (mm)": distance[0][
            "vista_error_max_mm"
        ]
        <= 0.001
    }
    if "cloudcompare_seconds" in peers:
        verdict["nominal: largest difference from CloudCompare's C2M where both answer (mm)"] = (
            peers["cloudcompare_difference_max_mm"] <= 0.001
        )
        verdict["nominal: times faster than CloudCompare's C2M"] = (
            peers["cloudcompare_compute_seconds"] >= 2.0 * peers["vista_seconds"]
        )
    if "open3d_seconds" in peers:
        verdict["nominal: times faster than Open3D's RaycastingScene"] = (
            peers["open3d_seconds"] > peers["vista_seconds"]
        )
    verdict["nominal: best-fit error (mm)"] = max(p["fit_error_mm"] for p in parts) <= 0.02
    verdict["nominal: best-fit error (degrees)"] = max(p["fit_error_deg"] for p in parts) <= 0.005
    truth = sum(p["true_areas"] for p in parts)
    verdict["nominal: findings recall"] = sum(p["matched"] for p in parts) >= 0.95 * truth
    area = sum(p["scanned_m2"] for p in parts)
    verdict["nominal: false findings per m²"] = sum(p["false"] for p in parts) <= 1.0 * area
    return verdict


def distance_table(rows: list[dict]) -> str:
    box, panel = rows
    lines = [
        f"box (analytic): vista's largest error {box['vista_error_max_mm'] * 1000:.2g} µm",
        "",
        "| | vista | Open3D RaycastingScene | CloudCompare C2M |",
        "|---|---|---|---|",
        f"| seconds | {panel['vista_seconds']:.2f} (index {panel['vista_index_seconds']:.2f}) | "
        f"{_get(panel, 'open3d_seconds')} | "
        + (
            f"{panel['cloudcompare_compute_seconds']:.2f} computing, {panel['cloudcompare_seconds']:.2f} in all |"
            if "cloudcompare_seconds" in panel
            else f"{panel.get('cloudcompare', '–')} |"
        ),
        f"| difference from vista p99 / max (µm) | – | {_um(panel, 'open3d_difference_p99_mm')} / "
        f"{_um(panel, 'open3d_difference_max_mm')} | {_um(panel, 'cloudcompare_difference_p99_mm')} / "
        f"{_um(panel, 'cloudcompare_difference_max_mm')} |",
    ]
    return f"{panel['case']}\n\n" + "\n".join(lines)


def parts_table(rows: list[dict]) -> str:
    lines = [
        "| case | best fit mm / ° (unwarped) | warped | deviation err p95 mm | true areas | found | matched | false |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['case']} (seed {row['seed']}) | {row['fit_error_mm']:.4f} / {row['fit_error_deg']:.4f} | "
            f"{row['warped_fit_error_mm']:.3f} / {row['warped_fit_error_deg']:.4f} | "
            f"{row['deviation_error_p95_mm']:.4f} | {row['true_areas']} | {row['found']} | "
            f"{row['matched']} | {row['false']} |"
        )
    truth = sum(r["true_areas"] for r in rows)
    recall = sum(r["matched"] for r in rows) / max(truth, 1)
    false = sum(r["false"] for r in rows) / max(sum(r["scanned_m2"] for r in rows), 1e-9)
    lines.append(f"\nrecall {recall:.3f} of {truth} true areas; {false:.2f} false findings per m²")
    return "\n".join(lines)


def _get(row: dict, key: str) -> str:
    return f"{row[key]:.2f}" if key in row else "–"


def _um(row: dict, key: str) -> str:
    return f"{row[key] * 1000:.3g}" if key in row else "–"
