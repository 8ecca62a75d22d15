"""Floor-camera odometry: the simulator agrees with its truth, its files round-trip, the
methods against truth at small scale, the commands and their errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from services.odometry import se2
from services.odometry.camera import FloorCamera
from services.odometry.drive import (
    THESIS_PATH_MM,
    Command,
    drive,
    loop_path,
    path_commands,
    random_path,
)
from services.odometry.floors import PROCEDURAL, image_floor, procedural_floor
from services.odometry.kinds import OdometryParams
from services.odometry.render import Effects, render
from services.odometry.tum import Trajectory2D, read_tum, write_tum
from supervisor.cli import app

SMALL = FloorCamera(width=240, height=180, fps=60.0, mm_per_px=0.6)
STILL = Effects(exposure_ms=0.0, vignetting=0.0, noise=0.0)


def test_se2_compose_inverse_and_integrate() -> None:
    rng = np.random.default_rng(1)
    poses = np.column_stack(
        [rng.normal(0, 500, 50), rng.normal(0, 500, 50), rng.uniform(-3, 3, 50)]
    )
    poses[0] = 0
    steps = se2.relative(poses)
    assert np.allclose(se2.integrate(steps), np.column_stack([poses[:, :2], se2.wrap(poses[:, 2])]))
    assert np.allclose(se2.compose(poses, se2.inverse(poses)), 0, atol=1e-9)


def test_the_loop_is_the_thesis_length_and_random_paths_keep_the_limits() -> None:
    loop = drive(loop_path())
    assert loop.distance_mm == pytest.approx(THESIS_PATH_MM, abs=2.0)
    assert np.allclose(loop.pose[0], 0)
    motion = drive(random_path(30.0, np.random.default_rng(4)))
    speed = np.hypot(*np.diff(motion.pose[:, :2], axis=0).T) / np.diff(motion.t_s)
    turn = np.degrees(np.abs(np.diff(np.unwrap(motion.pose[:, 2])))) / np.diff(motion.t_s)
    assert speed.max() < 2000 + 180 * np.radians(120) + 1  # the camera rides 120 mm ahead
    assert turn.max() <= 180.0 + 1e-6
    assert (speed < 1).any() and (turn > 29).any()  # stops and spins happen
    assert sum(c.seconds for c in path_commands("lawnmower", seconds=7.5, seed=0)) == 7.5


@pytest.mark.parametrize("name", ["concrete", "tiles", "wood"])
def test_procedural_floors_tile_without_seams(name: str) -> None:
    albedo = procedural_floor(name, seed=2, n=512).albedo
    inside = np.abs(np.diff(albedo, axis=1)).mean()
    across = np.abs(albedo[:, 0] - albedo[:, -1]).mean()
    assert across < 2 * inside


def test_frames_agree_with_the_true_motion() -> None:
    """Frame j resampled from frame i through the true relative motion matches frame j
    best: a motion off by a tenth of a pixel or 0.05° fits worse, one off by a pixel or
    0.5° much worse (x along the columns, y along the rows)."""
    floor = procedural_floor("concrete", seed=3, n=1024)
    motion = drive([Command(0.3, 300.0, 40.0)])
    times = np.array([0.1, 0.2])
    first, second = render(floor, SMALL, motion, times, STILL, np.random.default_rng(0))
    step = se2.relative(motion.at(times))[0]

    def error(move: np.ndarray) -> float:
        cols = np.arange(SMALL.width) - (SMALL.width - 1) / 2
        rows = np.arange(SMALL.height) - (SMALL.height - 1) / 2
        across, down = np.meshgrid(cols * SMALL.mm_per_px, rows * SMALL.mm_per_px)
        c, s = np.cos(move[2]), np.sin(move[2])
        x = (move[0] + c * across - s * down) / SMALL.mm_per_px + (SMALL.width - 1) / 2
        y = (move[1] + s * across + c * down) / SMALL.mm_per_px + (SMALL.height - 1) / 2
        warped = cv2.remap(
            first.astype(np.float32), x.astype(np.float32), y.astype(np.float32), cv2.INTER_LINEAR
        )
        inner = (slice(30, -30), slice(40, -40))
        return float(np.abs(warped[inner] - second[inner].astype(np.float32)).mean())

    assert abs(step[0]) > 3 and abs(step[2]) > 0.005  # it moved and turned
    exact = error(step)
    assert exact < 2.0  # grey levels: what bilinear resampling of a fine texture leaves
    px, degree = SMALL.mm_per_px, np.radians(1.0)
    for off in ([px, 0, 0], [0, px, 0], [0, 0, degree / 2]):
        assert error(step + off) > 1.7 * exact
    for off in ([px / 10, 0, 0], [-px / 10, 0, 0], [0, px / 10, 0], [0, -px / 10, 0]):
        assert error(step + off) > exact  # the truth is the best fit to a tenth of a pixel
    assert error(step + [0, 0, degree / 20]) > exact and error(step - [0, 0, degree / 20]) > exact


def test_tum_round_trip_and_errors(tmp_path) -> None:
    t = np.arange(5) / 60
    pose = np.column_stack([np.arange(5) * 3.25, -np.arange(5) * 1.5, np.linspace(0, 3.0, 5)])
    write_tum(tmp_path / "a.tum", Trajectory2D(t, pose, np.full(5, 0.5)))
    back = read_tum(tmp_path / "a.tum")
    assert np.allclose(back.pose, pose, atol=1e-6) and np.allclose(back.t_s, t, atol=1e-6)
    assert np.allclose(back.z_mm, 0.5)
    (tmp_path / "bad.tum").write_text("0 0 0 0 0 0 0 1\n0.1 1 2 3\n")
    with pytest.raises(ValueError, match=r"bad.tum:2: a pose is 8 finite numbers"):
        read_tum(tmp_path / "bad.tum")
    (tmp_path / "tilt.tum").write_text("0 0 0 0 0 0 0 1\n0.1 0 0 0 0.3 0 0 0.95\n")
    with pytest.raises(ValueError, match="pose 2 rotates out of the floor's plane"):
        read_tum(tmp_path / "tilt.tum")


def test_camera_json_round_trip_and_errors() -> None:
    camera = FloorCamera.thesis()
    assert FloorCamera.from_document(json.loads(json.dumps(camera.document()))) == camera
    assert np.hypot(*camera.footprint_mm) == pytest.approx(189.7)
    with pytest.raises(ValueError, match="no 'fps'"):
        FloorCamera.from_document({k: v for k, v in camera.document().items() if k != "fps"})
    with pytest.raises(ValueError, match="width must be a whole number"):
        FloorCamera.from_document({**camera.document(), "width": 640.5})


def test_image_floors(tmp_path) -> None:
    assert image_floor("gravel").albedo.shape == (3072, 3072)
    (tmp_path / "tiny.png").write_bytes(cv2.imencode(".png", np.zeros((8, 8), np.uint8))[1])
    with pytest.raises(ValueError, match="too small a floor"):
        image_floor(tmp_path / "tiny.png")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(ValueError, match="not an image file"):
        image_floor(tmp_path / "text.png")
    assert "low-texture" in PROCEDURAL


def test_cli_simulate_writes_the_contract(tmp_path) -> None:
    runner = CliRunner()
    out = tmp_path / "seq"
    done = runner.invoke(
        app,
        ["odometry", "simulate", str(out), "--floor", "gravel", "--path", "random"]
        + ["--seconds", "0.2", "--seed", "3"],
    )
    assert done.exit_code == 0, done.output
    frames = sorted((out / "frames").glob("*.png"))
    assert [f.name for f in frames[:2]] == ["000000.png", "000001.png"] and len(frames) == 13
    image = cv2.imread(str(frames[0]), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint8 and image.shape == (480, 640)
    camera = json.loads((out / "camera.json").read_text())
    assert set(camera) == {"width", "height", "fps", "mm_per_px", "height_mm", "focal_mm"}
    truth = read_tum(out / "truth.tum")
    assert len(truth) == 13 and np.allclose(truth.pose[0], 0)
    for args, phrase in [
        (["--floor", "marble"], "not a floor name"),
        (["--path", "spiral"], "known paths are loop, lawnmower, random"),
    ]:
        refused = runner.invoke(app, ["odometry", "simulate", str(tmp_path / "x"), *args])
        assert refused.exit_code == 2 and phrase in refused.output


@pytest.fixture(scope="module")
def short_sequence(tmp_path_factory):
    """0.5 s of the lawnmower path (speeding up along its first row) over asphalt, 640 × 480."""
    from services.odometry.simulate import simulate_sequence

    out = tmp_path_factory.mktemp("odometry") / "seq"
    simulate_sequence(out, floor="asphalt", path="lawnmower", seconds=0.5, seed=5)
    return out


def test_phase_correlation_peer_against_truth(short_sequence) -> None:
    from services.odometry.evaluate import evaluate
    from services.odometry.run import run_odometry

    camera = FloorCamera.from_document(json.loads((short_sequence / "camera.json").read_text()))
    result = run_odometry(short_sequence / "frames", camera, OdometryParams(method="phase"))
    scores = evaluate(result.trajectory, read_tum(short_sequence / "truth.tum"))
    assert scores.poses == 31 and result.flagged == 0
    assert scores.rmse_dx_mm < 0.1 and scores.rmse_dy_mm < 0.1 and scores.rmse_dtheta_deg < 0.2
    assert np.all(np.diff(result.sigma_xy_mm) >= 0)  # the uncertainty grows with distance


def test_cli_run_and_eval(short_sequence, tmp_path) -> None:
    runner = CliRunner()
    trajectory = tmp_path / "traj.tum"
    done = runner.invoke(
        app,
        ["odometry", "run", str(short_sequence / "frames"), "--camera"]
        + [str(short_sequence / "camera.json"), "-o", str(trajectory), "--plot"]
        + [str(tmp_path / "traj.png"), "--truth", str(short_sequence / "truth.tum")],
    )
    assert done.exit_code == 0, done.output
    assert "30 pairs" in done.output and (tmp_path / "traj.png").stat().st_size > 10_000
    report = json.loads((tmp_path / "traj.json").read_text())
    assert report["pairs"] == 30 and len(report["sigma_xy_mm"]) == 31
    assert read_tum(trajectory).pose.shape == (31, 3)
    scored = runner.invoke(
        app,
        ["odometry", "eval", str(trajectory), str(short_sequence / "truth.tum")]
        + ["-o", str(tmp_path / "eval.json")],
    )
    assert scored.exit_code == 0, scored.output
    figures = json.loads((tmp_path / "eval.json").read_text())
    assert set(figures) >= {"rmse_dx_mm", "rmse_dy_mm", "rmse_dtheta_deg", "final_error_m"}
    assert {"ate_rmse_m", "drift_percent", "heading_bias_deg"} <= set(figures)
    assert figures["final_nees"] >= 0 and figures["final_within_2_sigma"] is not None  # TRAJ.json
    (tmp_path / "camera.json").write_text('{"width": 640}')
    for args, phrase in [
        (["--camera", str(tmp_path / "camera.json")], "camera.json: no 'height'"),
        (
            ["--camera", str(short_sequence / "camera.json"), "--method", "magic"],
            "Invalid value for '--method'",
        ),
    ]:
        refused = runner.invoke(
            app, ["odometry", "run", str(short_sequence / "frames"), *args, "-o", str(trajectory)]
        )
        assert refused.exit_code == 2 and phrase in refused.output, refused.output
    empty = tmp_path / "empty"
    empty.mkdir()
    refused = runner.invoke(
        app,
        ["odometry", "run", str(empty), "--camera", str(short_sequence / "camera.json")]
        + ["-o", str(trajectory)],
    )
    assert refused.exit_code == 2 and "needs at least 2 PNG frames" in refused.output


def test_vista_direct_alignment_against_truth(short_sequence) -> None:
    """vista's method on the same frames: within the issue's per-step targets (0.03 mm,
    0.05°) while speeding up (motion blur growing), nothing flagged."""
    from services.odometry.evaluate import evaluate
    from services.odometry.run import run_odometry

    camera = FloorCamera.from_document(json.loads((short_sequence / "camera.json").read_text()))
    truth = read_tum(short_sequence / "truth.tum")
    one = run_odometry(short_sequence / "frames", camera)
    scores = evaluate(one.trajectory, truth)
    assert one.method == "vista" and one.flagged == 0
    assert scores.rmse_dx_mm < 0.03 and scores.rmse_dy_mm < 0.03
    assert scores.rmse_dtheta_deg < 0.05 and scores.final_error_m < 0.001


def test_direct_alignment_flags_a_plain_floor() -> None:
    from services.odometry.direct import align, prepare

    floor = procedural_floor("low-texture", seed=1, n=1024)
    motion = drive([Command(0.2, 300.0)])
    first, second = render(
        floor, SMALL, motion, np.array([0.1, 0.12]), Effects(), np.random.default_rng(2)
    )
    found = align(prepare(first), prepare(second), np.zeros(3))
    assert found.warning == "too little texture" and found.reason is None


def test_textured_points_carry_opencvs_sobel_gradients_and_the_most_texture() -> None:
    from services.odometry.kernels import textured_points

    albedo = procedural_floor("concrete", seed=3, n=256).albedo[:120, :160]
    level = (255 * albedo).astype(np.float32)
    gx = cv2.Sobel(level, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
    gy = cv2.Sobel(level, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
    for stride in (1, 2):
        xy, values, jacobians = textured_points(level, 4, stride, 500)
        cols, rows = (xy + [(160 - 1) / 2, (120 - 1) / 2]).round().astype(int).T
        assert ((rows - 4) % stride == 0).all() and ((cols - 4) % stride == 0).all()
        np.testing.assert_array_equal(values, level[rows, cols])
        np.testing.assert_allclose(jacobians[:, 0], gx[rows, cols], atol=1e-5)
        np.testing.assert_allclose(jacobians[:, 1], gy[rows, cols], atol=1e-5)
        np.testing.assert_allclose(
            jacobians[:, 2], -xy[:, 1] * gx[rows, cols] + xy[:, 0] * gy[rows, cols], atol=1e-3
        )
        # About the 500 most textured of the candidates: their energy tops the rest's.
        energy = (gx**2 + gy**2)[4:-4:stride, 4:-4:stride]
        assert 300 <= len(xy) <= 800
        assert np.median((gx**2 + gy**2)[rows, cols]) > np.quantile(energy, 0.9)


def test_a_rows_energy_is_the_pixels_gradients_energy_bit_for_bit() -> None:
    """``_energy_row`` (a row's loop, SIMD) against ``_gradient`` pixel by pixel: the same
    float32 operations in the same order, so the same textured points are chosen."""
    from services.odometry.kernels import _energy_row, _gradient

    level = (255 * procedural_floor("concrete", seed=5, n=64).albedo[:12, :40]).astype(np.float32)
    level[5, 7] = 3e17  # a huge value and a tiny one keep their rounding too
    level[6, 20] = 1e-30
    for r in range(1, 11):
        out = np.empty(38, np.float32)
        _energy_row(level[r - 1], level[r], level[r + 1], out)
        for c in range(1, 39):
            gx, gy = map(np.float32, _gradient(level, r, c))  # float32 outside too
            assert out[c - 1] == gx * gx + gy * gy, (r, c)


def test_the_texture_threshold_is_the_value_a_partition_puts_at_its_place() -> None:
    """``_select`` (by the values' bits) against ``np.partition``: spread, repeated,
    all-equal and zero values, subnormal and huge ones, every rank of small arrays."""
    from services.odometry.kernels import _select

    rng = np.random.default_rng(8)
    samples = [rng.gamma(0.5, 40.0, 9_000), np.round(rng.gamma(0.5, 4.0, 5_000)), np.ones(300)]
    samples += [rng.integers(0, 4, n).astype(float) for n in range(1, 12)]
    samples += [np.array([0.0, 1e-45, 3e-39, 1.0, 2.0**-126, 3e38, 1e-45, 0.0])]
    for values in samples:
        values = values.astype(np.float32)
        ranks = range(len(values)) if len(values) < 20 else (0, len(values) // 3, len(values) - 1)
        for rank in ranks:
            assert _select(values.copy(), rank) == np.partition(values, rank)[rank]


def test_oenet_trains_exports_and_runs_at_tiny_scale(short_sequence, tmp_path) -> None:
    """OE-Net (Table 6.1) built by the command on one short sequence for one epoch: the
    ONNX file says what it is, and `run --method oenet` uses it (its accuracy is the
    bench's business, after a real training run)."""
    from services.lib.nn.onnx_io import read_model
    from services.odometry.oenet import network

    # Table 6.1 layer by layer: 2 750 498 in the translation branch, 2 363 489 in the rotation
    assert sum(p.numel() for p in network().parameters()) == 5_113_987
    runner = CliRunner()
    model = tmp_path / "oenet.onnx"
    trained = runner.invoke(
        app,
        ["odometry", "train", str(short_sequence), "-o", str(model), "--epochs", "1"]
        + ["--batch", "16", "--device", "cpu"],
    )
    assert trained.exit_code == 0, trained.output
    metadata = read_model(model).metadata
    assert metadata["architecture"] == "oenet" and metadata["training"]["pairs"] == 30
    assert metadata["input"]["shape"] == ["batch", 2, 64, 64]
    done = runner.invoke(
        app,
        ["odometry", "run", str(short_sequence / "frames"), "--camera"]
        + [str(short_sequence / "camera.json"), "--method", "oenet", "--model", str(model)]
        + ["-o", str(tmp_path / "o.tum")],
    )
    assert done.exit_code == 0, done.output
    assert read_tum(tmp_path / "o.tum").pose.shape == (31, 3)
    for args, phrase in [
        (["--method", "oenet"], "OE-Net needs its model file"),
    ]:
        refused = runner.invoke(
            app,
            ["odometry", "run", str(short_sequence / "frames"), "--camera"]
            + [str(short_sequence / "camera.json"), *args, "-o", str(tmp_path / "x.tum")],
        )
        assert refused.exit_code == 2 and phrase in refused.output
    refused = runner.invoke(
        app, ["odometry", "train", str(short_sequence), "-o", str(model), "--arch", "vista"]
    )
    assert refused.exit_code == 2 and "Invalid value for '--arch'" in refused.output


def test_sequence_archives_unpack_in_frame_order_and_refuse_what_is_not_one(tmp_path) -> None:
    import io
    import tarfile
    import zipfile

    from services.odometry.sequence import SequenceError, extract_sequence, inspect_sequence
    from tests.sequences import pack, small_sequence

    folder = small_sequence(tmp_path / "seq", seconds=0.1)
    originals = sorted((folder / "frames").glob("*.png"))
    for suffix in ("seq.tar.gz", "seq.zip", "seq.tar"):
        archive = pack(folder, tmp_path / suffix)  # frames packed last to first
        found = inspect_sequence(archive)
        assert len(found.frames) == 7 and found.truth_member == "seq/truth.tum"
        assert (
            found.media_type
            == {
                "seq.tar.gz": "application/gzip",
                "seq.zip": "application/zip",
                "seq.tar": "application/x-tar",
            }[suffix]
        )
        out = tmp_path / f"out-{suffix}"
        extract_sequence(archive, out)
        assert [p.read_bytes() for p in sorted((out / "frames").glob("*.png"))] == [
            p.read_bytes() for p in originals
        ]
        assert read_tum(out / "truth.tum").pose.shape == (7, 3)
    assert inspect_sequence(pack(folder, tmp_path / "bare.zip", truth=False)).truth_member is None

    def zipped(members: dict[str, bytes]):
        path = tmp_path / f"case-{len(list(tmp_path.glob('case-*')))}.zip"
        with zipfile.ZipFile(path, "w") as out:
            for name, data in members.items():
                out.writestr(name, data)
        return path

    png = originals[0].read_bytes()
    camera = (folder / "camera.json").read_bytes()
    truth = (folder / "truth.tum").read_text().splitlines()
    cases = [
        ({"a/0.png": png, "a/1.png": png}, "no camera.json"),
        ({"a/0.png": png, "b/1.png": png, "camera.json": camera}, "must be in one folder"),
        ({"0.png": png, "camera.json": camera}, "needs at least 2 PNG frames"),
        ({"0.png": png, "1.png": png, "camera.json": b"{"}, "camera.json is not JSON"),
        ({"0.png": png, "1.png": png, "camera.json": b'{"width": 3}'}, "width = 3 is outside"),
        (
            {"0.png": png, "1.png": png, "camera.json": camera, "truth.tum": "\n".join(truth[:3])},
            "truth.tum has 3 poses for 2 frames",
        ),
        ({"0.png": png, "1.png": png, "camera.json": camera, "truth.tum": b"x"}, "not numbers"),
    ]
    for members, phrase in cases:
        with pytest.raises(SequenceError, match=phrase):
            inspect_sequence(zipped(members))
    numbered = {f"f/{k}.png": png for k in (10, 2, 1)} | {"f/camera.json": camera}
    numbered |= {"__MACOSX/f/._1.png": b"finder", "f/._2.png": b"finder"}
    assert inspect_sequence(zipped(numbered)).frames == ("f/1.png", "f/2.png", "f/10.png")
    (tmp_path / "notes.txt").write_text("frames")
    with pytest.raises(SequenceError, match="not a zip or tar archive"):
        inspect_sequence(tmp_path / "notes.txt")
    # a member's own path never decides where it is written
    evil = tmp_path / "evil.tar"
    with tarfile.open(evil, "w") as out:
        for name, data in [("../../0.png", png), ("../1.png", png), ("/etc/camera.json", camera)]:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            out.addfile(info, io.BytesIO(data))
    with pytest.raises(SequenceError, match="must be in one folder"):
        inspect_sequence(evil)
    with tarfile.open(evil, "w") as out:
        for name, data in [("../../0.png", png), ("../../1.png", png), ("camera.json", camera)]:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            out.addfile(info, io.BytesIO(data))
    landed = tmp_path / "deep" / "er" / "out"
    extract_sequence(evil, landed)
    assert sorted(p.name for p in (landed / "frames").iterdir()) == ["000000.png", "000001.png"]
    assert not (tmp_path / "deep" / "0.png").exists()


def test_bench_compares_the_methods_on_the_same_frames_and_keeps_them(tmp_path, capsys) -> None:
    from services.odometry.bench import Case, run_odometry_bench

    case = Case("tiny gravel", "floor", floor="gravel", seconds=0.3)
    out = tmp_path / "odometry.json"
    document = run_odometry_bench(
        out, oenet_model=None, work=tmp_path / "work", cases=(case,), loop=None, threads=1
    )
    row = document["sweep"][0]
    assert row["case"] == "tiny gravel" and set(row) >= {"vista", "phase"}
    assert row["vista"]["poses"] == 19 and row["vista"]["flagged"] == 0
    assert row["vista"]["drift_percent"] < 0.2 and row["vista"]["rmse_dtheta_deg"] < 0.05
    assert row["phase"]["poses"] == 19  # the peer ran on the same frames
    assert json.loads(out.read_text())["sweep"][0]["vista"] == row["vista"]
    assert "| tiny gravel |" in capsys.readouterr().out
    frame = tmp_path / "work" / "tiny-gravel" / "frames" / "000000.png"
    written = frame.stat().st_mtime_ns
    run_odometry_bench(
        out, oenet_model=None, work=tmp_path / "work", cases=(case,), loop=None, threads=1
    )
    assert frame.stat().st_mtime_ns == written  # the sequence was reused, not simulated again


def test_a_faint_floor_is_measured_with_a_warning_not_guessed(tmp_path) -> None:
    """On a floor whose texture is about the sensor's noise every pair is warned (too little
    texture) but keeps its measured motion with a larger σ: a guess (the motion before)
    would be off by the robot's acceleration."""
    from services.odometry.evaluate import evaluate
    from services.odometry.run import LOW_TEXTURE_SIGMA, run_odometry
    from services.odometry.simulate import simulate_sequence

    simulate_sequence(tmp_path, floor="low-texture", path="lawnmower", seconds=0.4, seed=2)
    camera = FloorCamera.from_document(json.loads((tmp_path / "camera.json").read_text()))
    result = run_odometry(tmp_path / "frames", camera, threads=1)
    scores = evaluate(result.trajectory, read_tum(tmp_path / "truth.tum"))
    assert result.flagged == 0 and result.warned == 24
    assert np.all(result.steps.sigma >= LOW_TEXTURE_SIGMA)
    assert scores.rmse_dx_mm < 0.1 and scores.rmse_dy_mm < 0.1 and scores.rmse_dtheta_deg < 0.1
    true_steps = se2.relative(read_tum(tmp_path / "truth.tum").pose)
    guessed = np.vstack([np.zeros(3), true_steps[:-1]])  # the motion before, as a bridge has it
    assert scores.rmse_dx_mm < 0.5 * np.sqrt(np.mean((guessed - true_steps)[:, 0] ** 2))


@pytest.mark.skipif(
    not __import__("services.odometry.bench", fromlist=["KITTI_FRAME"]).KITTI_FRAME.is_file(),
    reason="../shared/data (KITTI) is not beside this checkout",
)
def test_vista_on_a_real_camera_frame_as_the_floor(tmp_path) -> None:
    """A KITTI camera frame (a real sensor's texture and noise, a nearly plain sky) as the
    floor: vista's method keeps within its per-step targets; the phase peer on the same
    frames is several times worse."""
    from services.odometry.bench import KITTI_FRAME
    from services.odometry.evaluate import evaluate
    from services.odometry.run import run_odometry
    from services.odometry.simulate import simulate_sequence

    simulate_sequence(tmp_path, floor=str(KITTI_FRAME), path="random", seconds=1.0, seed=0)
    camera = FloorCamera.from_document(json.loads((tmp_path / "camera.json").read_text()))
    truth = read_tum(tmp_path / "truth.tum")
    vista = evaluate(run_odometry(tmp_path / "frames", camera, threads=2).trajectory, truth)
    phase = evaluate(
        run_odometry(
            tmp_path / "frames", camera, OdometryParams(method="phase"), threads=2
        ).trajectory,
        truth,
    )
    assert vista.rmse_dx_mm < 0.05 and vista.rmse_dy_mm < 0.05 and vista.rmse_dtheta_deg < 0.05
    assert vista.drift_percent < 0.2
    assert phase.rmse_dy_mm > 3 * vista.rmse_dy_mm


def test_pose_covariances_match_the_spread_of_noisy_integrations() -> None:
    """The closed-form propagation through SE(2) against 4 000 noisy integrations of the
    same steps: a heading error turns every later position, so the position's spread
    grows faster than the steps' own."""
    rng = np.random.default_rng(0)
    steps = np.column_stack(
        [rng.uniform(3, 8, 40), rng.normal(0, 0.5, 40), rng.normal(0.02, 0.02, 40)]
    )
    sigma = np.tile([0.05, 0.03, np.radians(0.01)], (40, 1))
    covariance = se2.pose_covariances(steps, sigma, 5e-4)
    ends = np.array(
        [
            se2.integrate(
                (steps + rng.normal(size=steps.shape) * sigma) * [1 + 5e-4 * rng.normal(), 1, 1]
            )[-1]
            for _ in range(4000)
        ]
    )
    spread = np.cov((ends - se2.integrate(steps)[-1]).T)
    assert np.allclose(covariance[-1], spread, rtol=0.1, atol=1e-6)
    # a heading error alone: each step's turns everything after it about the pose it ends at
    turned = se2.pose_covariances(steps, sigma * [0, 0, 1], 0.0)[-1]
    poses = se2.integrate(steps)
    lever = sum(
        sigma[k, 2] ** 2 * np.sum((poses[-1, :2] - poses[k + 1, :2]) ** 2) for k in range(40)
    )
    assert turned[0, 0] + turned[1, 1] == pytest.approx(lever)
    assert np.allclose(covariance[0], 0) and np.all(np.diff(covariance[:, 2, 2]) > 0)


def test_the_final_error_is_judged_against_its_covariance() -> None:
    """NEES by hand: 3 mm off along x with σ 3 mm, 0.1° off with σ 0.1° gives 2."""
    from services.odometry.evaluate import evaluate

    times = np.arange(3) / 60
    truth = Trajectory2D(times, np.array([[0, 0, 0], [5, 0, 0], [10, 0, 0.0]]))
    estimate = Trajectory2D(times, np.array([[0, 0, 0], [6, 0, 0], [13, 0, np.radians(0.1)]]))
    covariance = np.diag([9.0, 9.0, np.radians(0.1) ** 2])
    scores = evaluate(estimate, truth, covariance)
    assert scores.final_nees == pytest.approx(2.0)
    assert scores.final_within_2_sigma and scores.final_sigma_xy_m == pytest.approx(
        np.sqrt(18) / 1000
    )
    assert scores.heading_bias_deg == pytest.approx(0.05)
    assert evaluate(estimate, truth).final_nees is None


def test_a_straight_run_on_a_real_photograph_keeps_its_heading(tmp_path) -> None:
    """Three seconds straight over a KITTI camera frame of another drive as the floor: the
    heading's mean error a frame stays under 0.0002° (the remap OpenCV does rounds sample
    positions to 1/32 pixel, which alone left 0.0003° a frame on such a floor)."""
    from services.odometry.bench import KITTI_OTHER_DRIVES
    from services.odometry.evaluate import evaluate
    from services.odometry.run import run_odometry
    from services.odometry.simulate import simulate_sequence

    if not KITTI_OTHER_DRIVES.is_dir():
        pytest.skip("the shared KITTI sample is not here")
    simulate_sequence(
        tmp_path,
        floor=str(KITTI_OTHER_DRIVES / "000000.png"),
        commands=[Command(3.0, 400.0)],
        seed=1,
    )
    camera = FloorCamera.from_document(json.loads((tmp_path / "camera.json").read_text()))
    run = run_odometry(tmp_path / "frames", camera, threads=2)
    scores = evaluate(run.trajectory, read_tum(tmp_path / "truth.tum"), run.covariance[-1])
    assert abs(scores.heading_bias_deg) < 0.0002, scores
    assert abs(np.degrees(run.trajectory.pose[-1, 2])) < 0.03
    assert scores.final_within_2_sigma


def test_the_trajectory_plot_keeps_a_straight_path_readable(tmp_path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from services.odometry.report import _equal_and_readable

    figure, axes = plt.subplots()
    straight = np.column_stack([np.linspace(0, 5, 50), np.full(50, 0.001)])
    axes.plot(*straight.T)
    _equal_and_readable(axes, straight)
    figure.canvas.draw()
    x0, x1 = axes.get_xlim()
    y0, y1 = axes.get_ylim()
    assert (y1 - y0) >= (x1 - x0) / 3.5 and x0 <= 0 and x1 >= 5
    plt.close(figure)


def test_a_singular_final_covariance_leaves_the_nees_unmeasured() -> None:
    """A model that claims no heading error (a zero σ) cannot judge the final error: its
    NEES is unmeasured rather than a crash, and the 2σ check still stands."""
    from services.odometry.evaluate import evaluate
    from services.odometry.tum import Trajectory2D

    t = np.arange(5) / 60
    truth = Trajectory2D(t, np.column_stack([np.arange(5.0), np.zeros(5), np.zeros(5)]))
    estimate = Trajectory2D(t, np.column_stack([np.arange(5.0) * 1.01, np.zeros(5), np.zeros(5)]))
    result = evaluate(estimate, truth, np.diag([1.0, 1.0, 0.0]))
    assert result.final_nees is None and result.final_within_2_sigma is True
    assert evaluate(estimate, truth, np.diag([1.0, 1.0, 1e-6])).final_nees is not None


@pytest.mark.parametrize("ahead", [True, False])
def test_frames_are_read_in_order_and_a_bad_frame_is_named(tmp_path, ahead: bool) -> None:
    """Read ahead on a thread of their own or in the caller's thread: the same frames,
    the same errors."""
    import threading

    from services.odometry.frames import READ_AHEAD, read_frames

    def reading() -> bool:
        return any(t.name == "frame-reader" for t in threading.enumerate())

    camera = FloorCamera(width=8, height=6, fps=60.0, mm_per_px=0.6)
    files = []
    for k in range(3 * READ_AHEAD):
        path = tmp_path / f"{k:06d}.png"
        path.write_bytes(cv2.imencode(".png", np.full((6, 8), k, np.uint8))[1])
        files.append(path)
    frames = read_frames(files, camera, ahead=ahead)
    assert [int(f[0, 0]) for f in frames] == list(range(len(files)))
    # left after two frames: the reader stops instead of waiting on a full queue for ever
    frames = read_frames(files, camera, ahead=ahead)
    next(frames), next(frames)
    assert reading() == ahead
    frames.close()
    assert not reading()
    (tmp_path / "000004.png").write_bytes(cv2.imencode(".png", np.zeros((5, 8), np.uint8))[1])
    seen = []
    with pytest.raises(ValueError, match="000004.png: 8 × 5 pixels, but camera.json says 8 × 6"):
        seen.extend(read_frames(files, camera, ahead=ahead))
    assert len(seen) == 4
    (tmp_path / "000002.png").write_text("not a PNG")
    with pytest.raises(ValueError, match="000002.png: not an image OpenCV can read"):
        list(read_frames(files, camera, ahead=ahead))
