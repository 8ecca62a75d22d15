from __future__ import annotations

import json

import numpy as np
import pytest

from services.lib.pointcloud.ply import PointCloud
from services.scan.inspect import decimate, inspect_cloud
from tests.plyfiles import plane_grid


def test_grid_scan_spacing_density_and_area_match_the_plane():
    cloud = plane_grid(200, 300, spacing_mm=0.1)
    report = inspect_cloud(cloud)
    assert report.organized and (report.grid_height, report.grid_width) == (200, 300)
    assert report.mean_spacing_mm == pytest.approx(0.1, rel=1e-4)
    assert report.surface_area_mm2 == pytest.approx(199 * 0.1 * 299 * 0.1, rel=1e-4)
    assert report.density_per_mm2 == pytest.approx(60000 / (19.9 * 29.9), rel=1e-3)
    assert report.size_mm == pytest.approx((29.9, 19.9, 0.0), abs=1e-4)


def test_tilted_plane_area_uses_the_surface_not_the_footprint():
    cloud = plane_grid(100, 100, spacing_mm=0.2)
    points = cloud.points.copy()
    points[:, 2] = points[:, 0]  # 45 degrees about y: true area is sqrt(2) x footprint
    report = inspect_cloud(PointCloud(points=points, grid_shape=(100, 100)))
    assert report.surface_area_mm2 == pytest.approx(np.sqrt(2) * (99 * 0.2) ** 2, rel=1e-4)


def test_unorganized_density_from_nearest_neighbours():
    cloud = plane_grid(150, 150, spacing_mm=0.5)
    shuffled = PointCloud(points=np.random.default_rng(0).permutation(cloud.points))
    report = inspect_cloud(shuffled)
    assert not report.organized
    assert report.mean_spacing_mm == pytest.approx(0.5, rel=1e-4)
    assert report.density_per_mm2 == pytest.approx(4.0, rel=1e-3)


def test_unmeasured_pixels_are_reported_and_excluded():
    cloud = plane_grid(50, 50)
    points = cloud.points.copy()
    points[:250] = np.nan
    report = inspect_cloud(PointCloud(points=points, grid_shape=(50, 50)))
    assert report.valid_point_count == 2250 and not report.all_finite


def test_decimation_keeps_the_budget_and_covers_the_part():
    cloud = plane_grid(400, 500, spacing_mm=0.1)
    preview = decimate(cloud, max_points=5000, spacing_mm=0.1)
    assert 0.6 * 5000 <= len(preview.points) <= 5000
    low, high = preview.points.min(axis=0), preview.points.max(axis=0)
    assert low[:2] == pytest.approx((0.0, 0.0), abs=0.5)
    assert high[:2] == pytest.approx((49.9, 39.9), abs=0.5)


def test_decimation_leaves_small_clouds_alone():
    cloud = plane_grid(10, 10)
    assert len(decimate(cloud, max_points=1000, spacing_mm=0.1).points) == 100


def test_the_inspect_command_reports_as_the_job_does(tmp_path):
    """`vista scan inspect`: the job's report (the same core function) and its preview,
    the preview's budget a parameter as the job's; a file that is no PLY is refused."""
    from typer.testing import CliRunner

    from services.lib.pointcloud.ply import read_ply, write_ply
    from supervisor.cli import app

    def cli(*args: str):
        return CliRunner().invoke(app, list(args))

    scan = tmp_path / "plane.ply"
    write_ply(scan, plane_grid(200, 300, spacing_mm=0.1))
    report, preview = tmp_path / "report.json", tmp_path / "preview.ply"
    result = cli(
        "scan", "inspect", str(scan), "-o", str(report), "--preview", str(preview),
        "--preview-points", "5000",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "60000 points (60000 measured, organized 300 × 200)" in result.output
    written = json.loads(report.read_text())
    assert written["mean_spacing_mm"] == pytest.approx(0.1, rel=1e-4)
    assert 1000 < len(read_ply(preview).points) <= 5000
    refused = cli("scan", "inspect", str(report))
    assert refused.exit_code == 2 and "report.json" in refused.output
    too_few = cli("scan", "inspect", str(scan), "--preview-points", "10")
    assert too_few.exit_code == 2 and "preview-points" in too_few.output
