"""Stitching and clean-up against simulated ground truth (small grids; full scale is the bench)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from services.lib.pointcloud import scan_sim
from services.lib.pointcloud.grid import grid_normals, smooth_grid_normals, surrounded
from services.lib.pointcloud.ply import PointCloud, read_ply
from services.stitching.calibration import calibrate
from services.stitching.calibration_sim import simulate_calibration
from services.stitching.clean import isolated_points, loop_grid, loop_unorganized, voxel_merge
from services.stitching.kinds import NoiseModel, StitchParams
from services.stitching.quality import quality_report
from services.stitching.stitch import StitchConfig, stitch
from supervisor.cli import app


def _plane_grid(rows: int = 60, cols: int = 80, noise_mm: float = 0.02, seed: int = 0):
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(cols) * 0.1, np.arange(rows) * 0.1)
    z = 200.0 + 0.2 * x + rng.normal(0, noise_mm, x.shape)
    return np.stack([x, y, z], -1).astype(np.float32)


def test_grid_normals_face_the_sensor() -> None:
    grid = _plane_grid(noise_mm=0.0)
    normals = grid_normals(grid)
    expected = np.array([0.2, 0.0, -1.0]) / np.linalg.norm([0.2, 0.0, -1.0])
    assert np.allclose(normals.reshape(-1, 3), expected, atol=1e-4)  # borders: one-sided


def test_grid_normals_keep_their_surface_at_edges_and_holes() -> None:
    """A pixel beside one without a return (a panel's last pixel before its unseen side
    face) takes its normal from its own surface: a NaN normal would drop it from the
    stitch and move the edge by a spacing."""
    grid = _plane_grid(noise_mm=0.0)
    grid[:, 40:] = np.nan  # a side face the sensor does not see
    grid[:, 43:, 2] = 220.0
    grid[:, 43:, :2] = _plane_grid(noise_mm=0.0)[:, 43:, :2]  # the floor beyond, 20 mm down
    normals = grid_normals(grid)
    expected = np.array([0.2, 0.0, -1.0]) / np.linalg.norm([0.2, 0.0, -1.0])
    assert np.allclose(normals[:, 39], expected, atol=1e-4)  # beside the missing pixels
    assert np.allclose(normals[:, 43], [0.0, 0.0, -1.0], atol=1e-4)  # the floor's own
    assert np.isnan(normals[:, 40:43]).all()
    inner = surrounded(grid)
    assert inner[1:-1, 1:39].all() and not inner[:, 39].any() and not inner[0].any()


def test_smooth_normals_are_closer_to_the_true_plane_and_reach_the_edges() -> None:
    grid = _plane_grid(noise_mm=0.02)  # 0.1 mm spacing
    expected = np.array([0.2, 0.0, -1.0]) / np.linalg.norm([0.2, 0.0, -1.0])

    def angle_deg(normals: np.ndarray) -> np.ndarray:
        return np.degrees(np.arccos(np.clip(normals.reshape(-1, 3) @ expected, -1, 1)))

    adjacent, smooth = grid_normals(grid), smooth_grid_normals(grid, span_mm=2.0)
    inner = (slice(10, -10), slice(10, -10))
    assert np.median(angle_deg(smooth[inner])) < 0.2 * np.median(angle_deg(adjacent[inner]))
    # Near the border the wide stencil has no neighbours: adjacent pixels fill in.
    assert np.isfinite(smooth[1:-1, 1:-1]).all()


def _spiked_plane() -> tuple[np.ndarray, np.ndarray]:
    grid = _plane_grid()
    rng = np.random.default_rng(1)
    spikes = rng.choice(grid.shape[0] * grid.shape[1], 40, replace=False)
    grid.reshape(-1, 3)[spikes, 2] += rng.choice([-1, 1], 40) * rng.uniform(1.0, 3.0, 40)
    spiked = np.zeros(grid.shape[0] * grid.shape[1], bool)
    spiked[spikes] = True
    return grid, spiked


def test_loop_on_the_grid_flags_spikes_and_spares_the_surface() -> None:
    grid, spiked = _spiked_plane()
    grid.reshape(-1, 3)[5] = np.nan  # a missing pixel is not judged
    spiked[5] = False
    probability = loop_grid(grid).ravel()
    assert np.isnan(probability[5])
    assert np.mean(probability[spiked] > 0.8) >= 0.95
    assert np.mean(probability[~spiked & np.isfinite(probability)] > 0.8) < 0.01


def test_loop_on_unorganized_points_flags_most_spikes() -> None:
    # Weaker than on the grid: without the grid a spike's context is its k nearest
    # points, not its sensor neighbours, so the smallest spikes score lower.
    grid, spiked = _spiked_plane()
    probability = loop_unorganized(grid.reshape(-1, 3))
    assert np.mean(probability[spiked] > 0.5) >= 0.8
    assert np.mean(probability[~spiked] > 0.5) < 0.001


def test_voxel_merge_averages_and_the_final_filter_drops_strays() -> None:
    points = np.array([[0.01, 0.01, 0.01], [0.03, 0.05, 0.07], [1.01, 0.0, 0.0]], np.float32)
    normals = np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0]], np.float32)
    merged = voxel_merge(points, 0.1, normals=normals)
    assert merged.support.tolist() == [1, 2] or merged.support.tolist() == [2, 1]
    pair = int(np.argmax(merged.support))
    assert np.allclose(merged.points[pair], [0.02, 0.03, 0.04], atol=1e-6)
    assert np.allclose(merged.normals[pair], [0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-6)

    dense = _plane_grid().reshape(-1, 3)
    cloud = np.vstack([dense, [[50.0, 50.0, 50.0]]])
    isolated = isolated_points(cloud, cell_mm=2.0, min_points=10)
    assert isolated[-1] and not isolated[:-1].any()


@pytest.fixture(scope="module")
def stitched_angle():
    rng = np.random.default_rng(5)
    session = simulate_calibration(rng=rng)
    handeye = calibrate(session.base_T_flange, session.sensor_T_target)
    mesh = scan_sim.angle_profile()
    sensor = scan_sim.SensorModel(grid=(150, 231))
    robot = NoiseModel().model_dump(include={"robot_sigma_mm", "robot_sigma_deg"})
    scans = scan_sim.simulate_scans(
        mesh, session.true_flange_T_sensor, sensor=sensor, **robot, rng=rng
    )
    clouds = [PointCloud(points=g.reshape(-1, 3), grid_shape=g.shape[:2]) for g in scans.scans]
    result = stitch(clouds, scans.base_T_flange, handeye.flange_T_sensor)
    scanner = scan_sim.Scanner(mesh, scans.base_T_part, sensor)
    return result, scans, scanner


def test_stitched_points_lie_on_the_true_surface(stitched_angle) -> None:
    result, scans, scanner = stitched_angle
    error = scanner.distance_to_surface_mm(result.cloud.points)
    assert np.mean(error) < 0.12 and np.percentile(error, 99) < 0.35
    stray = sum(s.outliers for s in result.scans)
    assert stray > 0  # the simulator's stray returns were found
    assert result.cloud.normals is not None and len(result.cloud.normals) == len(error)


def test_quality_report_matches_the_model_box(stitched_angle) -> None:
    result, scans, _ = stitched_angle
    corners = scans.mesh.vertices + scans.base_T_part[:3, 3]
    report = quality_report(
        [s.points for s in result.scans],
        result.cloud.points,
        model_bounds_mm=(corners.min(0), corners.max(0)),
    )
    assert len(report.pairs) >= 2  # three scans in a row overlap pairwise
    assert report.overall.mean_mm < 0.25 and report.overall.count > 10_000
    # Along the profile the scans reach the part's ends; across, the legs are fully seen.
    assert max(report.model_bounds_difference_mm) < 1.0


def test_cli_simulate_calibrate_stitch(tmp_path) -> None:
    runner = CliRunner()
    assert runner.invoke(app, ["stitching", "simulate", str(tmp_path)]).exit_code == 0
    handeye = tmp_path / "handeye.json"
    calibrated = runner.invoke(
        app,
        ["stitching", "calibrate", str(tmp_path / "pairs.json"), "-o", str(handeye)]
        + ["--robot-sigma-mm", "0.06"],
    )
    assert calibrated.exit_code == 0, calibrated.output
    out, report = tmp_path / "out" / "stitched.ply", tmp_path / "out" / "report.json"
    stitch_args = ["--handeye", str(handeye), "-o", str(out), "--report", str(report)]
    done = runner.invoke(app, ["stitching", "stitch", str(tmp_path / "scans.json"), *stitch_args])
    assert done.exit_code == 0, done.output
    document = json.loads(report.read_text())
    assert document["points"] == len(read_ply(out).points) > 0
    assert document["pairs"] and document["overall"]["mean_mm"] < 0.3
    assert report.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    refined = runner.invoke(
        app,
        [
            "stitch",
            str(tmp_path / "scans.json"),
            *stitch_args,
            "--icp",
            "bounded",
            "--truth",
            str(tmp_path / "truth.json"),
        ],
    )
    assert refined.exit_code == 0, refined.output
    document = json.loads(report.read_text())
    assert document["icp"]["method"] == "bounded" and len(document["icp"]["scans"]) == 3
    assert document["icp"]["robot_sigma_mm"] == 0.06  # the calibration's, not a default
    assert document["true_error"]["mean_mm"] < 0.15
    assert document["scan_pose_error"]["max_translation_mm"] < 0.5
    assert max(document["model_bounds_difference_mm"]) < 1.0

    scans = json.loads((tmp_path / "scans.json").read_text())
    scans["scans"][1]["file"] = "missing.ply"
    (tmp_path / "bad.json").write_text(json.dumps(scans))
    refused = runner.invoke(app, ["stitch", str(tmp_path / "bad.json"), *stitch_args])
    assert refused.exit_code == 2 and "scans[1].file 'missing.ply' does not exist" in refused.output
    coarse = runner.invoke(
        app, ["stitch", str(tmp_path / "scans.json"), *stitch_args, "--voxel-mm", "11"]
    )
    assert coarse.exit_code == 2 and "--voxel-mm" in coarse.output
    (tmp_path / "scan_002.ply").write_bytes(b"nope")
    unreadable = runner.invoke(app, ["stitch", str(tmp_path / "scans.json"), *stitch_args])
    assert unreadable.exit_code == 2
    assert "scan_002.ply: the file does not start with the PLY magic" in unreadable.output


def test_simulate_and_bench_are_stitching_verbs_with_the_old_spellings_hidden(tmp_path) -> None:
    runner = CliRunner()
    verbs = runner.invoke(app, ["stitching", "--help"]).output
    assert " simulate " in verbs and " bench " in verbs
    for group in ("simulate", "bench"):
        listed = runner.invoke(app, [group, "--help"]).output
        assert " stitching " not in listed, listed
        old = runner.invoke(app, [group, "stitching", "--help"])
        assert old.exit_code == 0 and f"vista stitching {group}" in old.output
    done = runner.invoke(app, ["simulate", "stitching", str(tmp_path), "--poses", "4"])
    assert done.exit_code == 0 and (tmp_path / "truth.json").is_file(), done.output


def test_stitch_settings_are_the_job_parameters() -> None:
    """StitchConfig's defaults and ranges are StitchParams'; the ICP of a stitch is bounded
    by the robot noise its calibration was given."""
    params = StitchParams()
    config = StitchConfig()
    assert (config.voxel_mm, config.loop_threshold) == (params.voxel_mm, params.loop_threshold)
    assert StitchConfig.from_params(params, {}) == config  # icp "none": kinematic poses
    for wrong in ({"voxel_mm": 0.0}, {"voxel_mm": 11.0}, {"loop_threshold": 1.5}):
        with pytest.raises(ValueError, match=next(iter(wrong))):
            StitchConfig(**wrong)
    calibration = {"noise": {"robot_sigma_mm": 0.1}, "sigma_translation_mm": 0.03}
    bounded = StitchConfig.from_params(StitchParams(icp="bounded"), calibration).icp
    assert (bounded.method, bounded.start) == ("bounded", params.icp_start)
    assert (bounded.robot_sigma_mm, bounded.calibration_sigma_mm) == (0.1, 0.03)
    assert bounded.robot_sigma_deg == NoiseModel().robot_sigma_deg  # not recorded: default


def test_a_handeye_with_impossible_noise_is_refused(tmp_path) -> None:
    from services.stitching.files import StitchingFileError, read_handeye

    path = tmp_path / "handeye.json"
    document = {"flange_T_sensor": np.eye(4).tolist(), "noise": {"robot_sigma_mm": -1}}
    path.write_text(json.dumps(document))
    with pytest.raises(StitchingFileError, match="noise.robot_sigma_mm: Input should be greater"):
        read_handeye(path)
