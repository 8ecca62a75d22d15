"""Hand–eye calibration against simulated truth: vista, the thesis's and OpenCV's methods."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from services.lib.pointcloud.transforms import check_rigid, pose_error, to_json
from services.stitching.calibration import (
    OPENCV_METHODS,
    CalibrationError,
    calibrate,
    calibrate_thesis,
    park_martin,
)
from services.stitching.calibration_sim import simulate_calibration
from services.stitching.files import StitchingFileError, read_handeye, read_pairs, write_pairs
from services.stitching.kinds import NoiseModel
from supervisor.cli import app

NOISELESS = dict(robot_sigma_mm=0.0, robot_sigma_deg=0.0, sensor_sigma_mm=0.0, sensor_sigma_deg=0.0)


def _session(seed: int, **kwargs):
    return simulate_calibration(rng=np.random.default_rng(seed), **kwargs)


def _error(result, session) -> tuple[float, float]:
    return pose_error(result.flange_T_sensor, session.true_flange_T_sensor)


def test_every_method_is_exact_without_noise() -> None:
    session = _session(1, **NOISELESS)
    start = park_martin(session.base_T_flange, session.sensor_T_target)
    assert pose_error(start, session.true_flange_T_sensor) < (1e-6, 1e-6)
    for method in ("vista", *OPENCV_METHODS):
        result = calibrate(session.base_T_flange, session.sensor_T_target, method=method)
        translation_mm, rotation_deg = _error(result, session)
        assert translation_mm < 1e-3 and rotation_deg < 1e-4, method
        assert result.residual_mm < 1e-3, method
        assert pose_error(result.base_T_target, session.true_base_T_target)[0] < 1e-3


def test_thesis_basin_hopping_finds_the_mount_from_the_identity() -> None:
    session = _session(2, **NOISELESS)
    result = calibrate_thesis(session.base_T_flange, session.sensor_T_target, hops=5)
    translation_mm, rotation_deg = _error(result, session)
    assert translation_mm < 0.01 and rotation_deg < 0.01


def test_vista_at_the_thesis_noise_matches_truth_and_its_own_uncertainty() -> None:
    errors, sigmas = [], []
    for seed in range(8):
        session = _session(100 + seed)
        result = calibrate(session.base_T_flange, session.sensor_T_target)
        errors.append(_error(result, session))
        sigmas.append((result.sigma_translation_mm, result.sigma_rotation_deg))
        assert result.dropped == ()
    translation_mm, rotation_deg = np.median(errors, axis=0)
    assert translation_mm < 0.1 and rotation_deg < 0.03
    # The stated 1σ is the right size: the errors are neither far below nor far above it.
    ratio = np.median(np.array(errors) / np.array(sigmas), axis=0)
    assert np.all((ratio > 0.3) & (ratio < 3.0)), ratio


def test_vista_drops_the_mis_detected_pair_where_opencv_degrades() -> None:
    session = _session(7, corrupt=1)
    vista = calibrate(session.base_T_flange, session.sensor_T_target)
    assert [d.index for d in vista.dropped] == list(session.corrupted)
    assert vista.dropped[0].residual_mm > 1.0
    assert session.corrupted[0] not in vista.used_pairs
    translation_mm, rotation_deg = _error(vista, session)
    assert translation_mm < 0.15 and rotation_deg < 0.05
    tsai = calibrate(session.base_T_flange, session.sensor_T_target, method="tsai")
    assert _error(tsai, session)[0] > 2 * translation_mm


def test_unusable_pairs_are_refused_with_a_reason() -> None:
    session = _session(3)
    with pytest.raises(CalibrationError, match="at least 3 pairs"):
        calibrate(session.base_T_flange[:2], session.sensor_T_target[:2])
    same = np.repeat(session.base_T_flange[:1], 5, axis=0)
    with pytest.raises(CalibrationError, match="tilt and turn"):
        calibrate(same, session.sensor_T_target[:5])
    with pytest.raises(ValidationError, match="robot_sigma_mm\n  Input should be greater than 0"):
        NoiseModel(robot_sigma_mm=0.0)
    with pytest.raises(CalibrationError, match="unknown method"):
        calibrate(session.base_T_flange, session.sensor_T_target, method="magic")


def test_pairs_file_round_trip_and_errors(tmp_path) -> None:
    session = _session(4)
    path = tmp_path / "pairs.json"
    write_pairs(path, session.base_T_flange, session.sensor_T_target)
    flange, target = read_pairs(path)
    assert np.allclose(flange, session.base_T_flange) and np.allclose(
        target, session.sensor_T_target
    )

    def refused(document: object) -> str:
        path.write_text(json.dumps(document))
        with pytest.raises(StitchingFileError) as info:
            read_pairs(path)
        return str(info.value)

    good = {"base_T_flange": to_json(np.eye(4)), "sensor_T_target": to_json(np.eye(4))}
    assert "at least one pair" in refused({"pairs": []})
    assert "pairs[0] has no sensor_T_target" in refused(
        {"pairs": [{"base_T_flange": good["base_T_flange"]}]}
    )
    nan = to_json(np.eye(4))
    nan[0][3] = float("nan")
    assert "pairs[1].base_T_flange: contains NaN" in refused(
        {"pairs": [good, {**good, "base_T_flange": nan}]}
    )
    sheared = to_json(np.eye(4))
    sheared[0][1] = 0.5
    assert "not a rotation" in refused({"pairs": [{**good, "sensor_T_target": sheared}]})
    assert "must be 4×4" in refused({"pairs": [{**good, "base_T_flange": [[1, 0], [0, 1]]}]})
    path.write_text("{nope")
    with pytest.raises(StitchingFileError, match="not valid JSON"):
        read_pairs(path)


def test_rounded_matrices_are_snapped_to_rotations() -> None:
    rotation = np.round(_session(5).true_flange_T_sensor, 6)
    snapped = check_rigid(rotation.tolist(), "M")
    assert np.allclose(snapped[:3, :3] @ snapped[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.abs(snapped - rotation).max() < 1e-5


def test_cli_simulate_then_calibrate(tmp_path) -> None:
    runner = CliRunner()
    simulated = runner.invoke(app, ["stitching", "simulate", str(tmp_path), "--corrupt", "1"])
    assert simulated.exit_code == 0, simulated.output
    out = tmp_path / "handeye.json"
    calibrate_args = ["stitching", "calibrate", str(tmp_path / "pairs.json"), "-o", str(out)]
    done = runner.invoke(app, calibrate_args)
    assert done.exit_code == 0, done.output
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert f"dropped pair {truth['corrupted_pairs'][0]}" in done.output
    flange_T_sensor, document = read_handeye(out)
    assert pose_error(flange_T_sensor, np.array(truth["flange_T_sensor"])) < (0.15, 0.05)
    assert document["method"] == "vista" and document["residual_mm"] < 0.2
    assert {"base_T_target", "sigma_translation_mm", "dropped_pairs"} <= set(document)
    assert document["noise"] == NoiseModel().model_dump()  # what a bounded ICP stitch reads

    # The old spelling still works; the noise options are recorded for the stitch.
    noisier = runner.invoke(app, [*calibrate_args[1:], "--robot-sigma-mm", "0.08"])
    assert noisier.exit_code == 0, noisier.output
    assert read_handeye(out)[1]["noise"]["robot_sigma_mm"] == 0.08
    bad_method = runner.invoke(app, [*calibrate_args, "--method", "x"])
    assert bad_method.exit_code == 2 and "Invalid value for '--method'" in bad_method.output
    missing = runner.invoke(app, ["calibrate", str(tmp_path / "nope.json"), "-o", str(out)])
    assert missing.exit_code == 2 and "no such file" in missing.output


def test_method_lists_are_the_job_kinds_words() -> None:
    """The calibration and ICP methods are declared once, in the kinds module; the code,
    the commands and the jobs read them (OpenCV's by its constant's name)."""
    from typing import get_args

    import cv2

    from services.stitching import icp
    from services.stitching.calibration import METHODS
    from services.stitching.kinds import CalibrationMethod, IcpMethod

    assert METHODS == get_args(CalibrationMethod) == ("vista", "thesis", *OPENCV_METHODS)
    assert all(hasattr(cv2, f"CALIB_HAND_EYE_{m.upper()}") for m in OPENCV_METHODS)
    assert get_args(IcpMethod) == ("none", *icp.METHODS)


def test_noise_defaults_are_the_calibrate_parameters() -> None:
    """One declaration of the calibration noise (the job's parameters): the simulators and
    ICP take their defaults from it."""
    import inspect

    from services.stitching.icp import IcpConfig
    from services.stitching.kinds import CalibrateParams

    noise = NoiseModel()
    assert CalibrateParams().model_dump(exclude={"method"}) == noise.model_dump()
    simulated = inspect.signature(simulate_calibration).parameters
    assert {name: simulated[name].default for name in NoiseModel.model_fields} == (
        noise.model_dump()
    )
    assert (IcpConfig().robot_sigma_mm, IcpConfig().robot_sigma_deg) == (
        noise.robot_sigma_mm,
        noise.robot_sigma_deg,
    )
