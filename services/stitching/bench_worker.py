"""One side of the full-scale stitching benchmark, in its own process so its peak memory is
its own: ``python -m services.stitching.bench_worker vista|open3d EXAMPLE_DIR OUT.ply``.

Reads the scans (not timed), runs stitch + clean, writes the cloud and prints one JSON line:
seconds, peak RSS, the RSS with the scans loaded, the output point count, and for vista
the overlap quality (measured after the clock and the memory peak were read).
"""

from __future__ import annotations

import json
import resource
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from services.lib.pointcloud.grid import grid_spacing_mm
from services.lib.pointcloud.ply import PointCloud, read_ply, write_ply
from services.stitching.files import read_handeye, read_scans
from services.stitching.quality import quality_report
from services.stitching.stitch import StitchConfig, StitchResult, stitch

CONFIG = StitchConfig()
OPEN3D_NEIGHBOURS = 8
"""Open3D normals and statistical outliers from the 8 nearest points: vista's 3 × 3 window."""
OPEN3D_STD_RATIO = 2.0
OPEN3D_FINAL_RADIUS_MM = 0.5
"""Open3D's final filter: fewer than CONFIG.min_points neighbours within this radius (or
2.5 scan spacings on coarser scans, so a plain surface keeps its points)."""


def _rss_mb() -> float:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def run_vista(
    clouds: list[PointCloud], base_T_flange: np.ndarray, flange_T_sensor: np.ndarray
) -> tuple[PointCloud, StitchResult]:
    result = stitch(clouds, base_T_flange, flange_T_sensor, config=CONFIG)
    return result.cloud, result


def run_open3d(
    clouds: list[PointCloud], base_T_flange: np.ndarray, flange_T_sensor: np.ndarray
) -> tuple[PointCloud, None]:
    """The same steps with Open3D's API, as a user of it would write them."""
    import open3d as o3d

    merged = o3d.geometry.PointCloud()
    for cloud, pose in zip(clouds, base_T_flange @ flange_T_sensor, strict=True):
        points = cloud.points[np.isfinite(cloud.points).all(axis=1)]
        scan = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
        scan.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=OPEN3D_NEIGHBOURS + 1))
        scan.orient_normals_towards_camera_location(np.zeros(3))
        scan, _ = scan.remove_statistical_outlier(OPEN3D_NEIGHBOURS, OPEN3D_STD_RATIO)
        scan.transform(pose)
        merged += scan
    merged = merged.voxel_down_sample(CONFIG.voxel_mm)
    spacing = grid_spacing_mm(clouds[0].points.reshape(*clouds[0].grid_shape, 3))
    radius = max(OPEN3D_FINAL_RADIUS_MM, 2.5 * spacing)
    merged, _ = merged.remove_radius_outlier(CONFIG.min_points, radius)
    cloud = PointCloud(
        points=np.asarray(merged.points, dtype=np.float32),
        normals=np.asarray(merged.normals, dtype=np.float32),
    )
    return cloud, None


def main() -> None:
    which, example, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    files, base_T_flange = read_scans(example / "scans.json")
    flange_T_sensor, _ = read_handeye(example / "handeye.json")
    clouds = [read_ply(file) for file in files]
    loaded_mb = _rss_mb()
    started = time.perf_counter()
    runner = {"vista": run_vista, "open3d": run_open3d}[which]
    cloud, result = runner(clouds, base_T_flange, flange_T_sensor)
    seconds = time.perf_counter() - started
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    extra = {}
    if result is not None:  # vista's overlap quality (Fig. 6.2), after the clock stopped
        quality = quality_report([s.points for s in result.scans], result.cloud.points)
        extra = {
            "steps_s": result.seconds,
            "overlap": asdict(quality.overall),
            "overlap_pairs": len(quality.pairs),
        }
    write_ply(out, cloud, comments=(f"{which} stitched, base frame, mm",))
    print(
        json.dumps(
            {
                "pipeline": which,
                "seconds": seconds,
                "peak_rss_mb": peak_mb,
                "loaded_rss_mb": loaded_mb,
                "input_points": int(sum(np.isfinite(c.points).all(axis=1).sum() for c in clouds)),
                "output_points": len(cloud.points),
                **extra,
            }
        )
    )


if __name__ == "__main__":
    main()
