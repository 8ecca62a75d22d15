"""ICP on simulated scans: the thesis's collapse without a start, and vista's bounded refine."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from services.lib.pointcloud import scan_sim
from services.lib.pointcloud.ply import PointCloud
from services.lib.pointcloud.transforms import from_rotvec, pose_error
from services.stitching.calibration_sim import nominal_flange_T_sensor
from services.stitching.icp import IcpConfig, transform_twist, twist_transform
from services.stitching.kinds import NoiseModel
from services.stitching.stitch import StitchConfig, stitch


@pytest.fixture(scope="module")
def flat_scans():
    rng = np.random.default_rng(3)
    flange_T_sensor = nominal_flange_T_sensor(rng)
    mesh = scan_sim.flat_panel()
    sensor = scan_sim.SensorModel(grid=(120, 185))
    robot = NoiseModel().model_dump(include={"robot_sigma_mm", "robot_sigma_deg"})
    scans = scan_sim.simulate_scans(mesh, flange_T_sensor, sensor=sensor, **robot, rng=rng)
    clouds = [PointCloud(points=g.reshape(-1, 3), grid_shape=g.shape[:2]) for g in scans.scans]
    true_base_T_scan = scans.true_base_T_flange @ flange_T_sensor
    return clouds, scans, flange_T_sensor, true_base_T_scan


def _pose_errors(base_T_scan: np.ndarray, true_base_T_scan: np.ndarray) -> np.ndarray:
    pairs = zip(base_T_scan, true_base_T_scan, strict=True)
    return np.array([pose_error(a, b) for a, b in pairs])


def test_twist_round_trip() -> None:
    twist = np.array([0.01, -0.02, 0.005, 1.0, -2.0, 0.5])
    centre = np.array([500.0, -100.0, 250.0])
    assert np.allclose(transform_twist(twist_transform(twist, centre), centre), twist)


def test_without_the_kinematic_start_scans_collapse_onto_each_other(flat_scans) -> None:
    clouds, scans, flange_T_sensor, true_base_T_scan = flat_scans
    for method in ("point-to-point", "point-to-plane"):
        config = StitchConfig(icp=IcpConfig(method=method, start="none"))
        result = stitch(clouds, scans.base_T_flange, flange_T_sensor, config=config)
        extent = np.ptp(result.cloud.points, axis=0)
        # Every scan lands on the first: the 300 × 200 mm panel shrinks to one field.
        assert extent[0] < 170 and extent[1] < 110, (method, extent)
        assert _pose_errors(result.base_T_scan, true_base_T_scan)[:, 0].max() > 100


def test_bounded_refine_never_leaves_the_kinematic_bound(flat_scans) -> None:
    clouds, scans, flange_T_sensor, true_base_T_scan = flat_scans
    reported = scans.base_T_flange.copy()
    # A robot pose 0.6 mm and 0.03° off (12σ): the surface pulls the scan back, but only
    # as far as the kinematic covariance allows.
    reported[4] = reported[4] @ from_rotvec(np.radians([0.03, 0, 0]), [0.3, 0, 0.5])
    config = IcpConfig(method="bounded")
    result = stitch(clouds, reported, flange_T_sensor, config=StitchConfig(icp=config))
    bound = np.sqrt(chi2.ppf(config.bound_probability, 6))
    assert all(a.mahalanobis <= bound + 1e-6 for a in result.alignments[1:])
    assert result.alignments[4].clipped
    assert sum(a.clipped for a in result.alignments) <= 2  # the others fit inside
    # Within the bound a scan moves by tenths of a millimetre, never by millimetres.
    assert max(a.moved_mm for a in result.alignments) < 0.6
    errors = _pose_errors(result.base_T_scan, true_base_T_scan)
    kinematic = _pose_errors(reported @ flange_T_sensor, true_base_T_scan)
    assert errors[4, 0] < kinematic[4, 0]  # moved towards the truth
    others = np.arange(len(errors)) != 4
    assert errors[others, 0].max() < 0.3


def test_bounded_refine_needs_the_kinematic_start() -> None:
    with pytest.raises(ValueError, match="kinematic start"):
        IcpConfig(method="bounded", start="none")
    with pytest.raises(ValueError, match="ICP method"):
        IcpConfig(method="generalized")
