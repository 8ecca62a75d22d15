"""Monocular depth: the evaluation against hand-computed metrics, KITTI's formats, the
simulator against its own truth, the commands and their errors."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from services.depth.camera import PinholeCamera, kitti_camera
from services.depth.drive import read_calibration, read_drive
from services.depth.metrics import evaluate_image
from services.depth.render import render
from services.depth.scene import random_scene
from services.lib.kitti import read_depth_png, write_depth_png
from supervisor.cli import app

KITTI_RAW = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti-raw-2011_09_26"
SMALL = kitti_camera().resized(320, 96)


def test_metrics_against_a_case_computed_by_hand() -> None:
    gt = np.array([[2.0, 4.0], [0.0, 8.0]])  # the 0 is unmeasured
    pred = np.array([[1.0, 4.0], [5.0, 10.0]])
    got = evaluate_image(gt, pred, crop="none").errors
    # valid pairs (2, 1), (4, 4), (8, 10)
    assert got.abs_rel == pytest.approx((1 / 2 + 0 + 2 / 8) / 3)
    assert got.sq_rel == pytest.approx((1 / 2 + 0 + 4 / 8) / 3)
    assert got.rmse == pytest.approx(math.sqrt(5 / 3))
    assert got.rmse_log == pytest.approx(math.sqrt((math.log(2) ** 2 + math.log(0.8) ** 2) / 3))
    # ratios 2, 1, 1.25: 1.25 is not < 1.25, and 2 is not < 1.25³ = 1.953
    assert (got.delta1, got.delta2, got.delta3) == pytest.approx((1 / 3, 2 / 3, 2 / 3))


def test_metrics_median_scaling_clipping_resizing_and_crops() -> None:
    gt = np.full((100, 100), 10.0)
    scaled = evaluate_image(gt, np.full((100, 100), 20.0), crop="none", median_scaling=True)
    assert scaled.scale == pytest.approx(0.5) and scaled.errors.abs_rel == pytest.approx(0)
    far = evaluate_image(np.full((4, 4), 70.0), np.full((4, 4), 100.0), crop="none")
    assert far.errors.abs_rel == pytest.approx(10 / 70)  # clipped to 80 m first
    half = evaluate_image(gt, np.full((50, 50), 10.0), crop="none")  # resized to the truth
    assert half.pixels == 100 * 100 and half.errors.rmse == pytest.approx(0)
    # Garg's crop keeps rows 40–98 and columns 3–95 of a 100 × 100 image
    assert evaluate_image(gt, gt, crop="garg").pixels == (99 - 40) * (96 - 3)
    assert evaluate_image(gt, gt, crop="eigen").pixels == (91 - 33) * (96 - 3)
    gt[:, :] = 0
    with pytest.raises(ValueError, match="no ground-truth pixel"):
        evaluate_image(gt, gt)


def test_depth_png_round_trip_and_refusal(tmp_path: Path) -> None:
    depth = np.array([[0.0, 1.0, 80.5], [300.0, np.nan, 3.14159]])
    write_depth_png(tmp_path / "d.png", depth)
    back = read_depth_png(tmp_path / "d.png")
    assert back[0, 1] == 1.0 and back[0, 2] == 80.5
    assert back[1, 2] == pytest.approx(3.14159, abs=1 / 512)
    assert back[1, 0] == 0 and back[1, 1] == 0 and back[0, 0] == 0  # beyond 256 m, NaN, none
    cv2.imwrite(str(tmp_path / "grey.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="16-bit"):
        read_depth_png(tmp_path / "grey.png")


@pytest.mark.skipif(not KITTI_RAW.is_dir(), reason="the shared KITTI sample is not here")
def test_reads_the_real_kitti_drive() -> None:
    drive = read_drive(KITTI_RAW)
    assert len(drive.names) == 40 and drive.right is None and drive.poses is None
    assert drive.camera.width == 1242 and drive.camera.height == 375
    assert drive.camera.K[0, 0] == pytest.approx(721.5377)
    depth = read_depth_png(drive.depth[0])
    valid = depth > 0
    assert 10_000 < valid.sum() < 30_000 and depth[valid].min() > 1 and depth.max() < 90


def test_reads_kittis_calib_cam_to_cam(tmp_path: Path) -> None:
    (tmp_path / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\n"
        "P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 "
        "7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03\n"
        "P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 "
        "7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03\n"
    )
    drive = tmp_path / "2011_09_26_drive_0001_sync"
    drive.mkdir()
    camera = read_calibration(drive, (1242, 375))  # found in the date folder above
    assert camera.K[0, 2] == pytest.approx(609.5593)
    assert camera.baseline_m == pytest.approx(0.5327, abs=1e-4)
    with pytest.raises(ValueError, match="no calib"):
        read_calibration(tmp_path / "elsewhere" / "deeper", (1, 1))


def test_simulated_road_depth_is_the_ground_plane() -> None:
    scene = random_scene(4)
    street_T_camera = np.eye(4)
    street_T_camera[:3, 3] = (scene.ego_x_m, -1.65, 0.0)
    depth = render(scene, SMALL, street_T_camera, noise_seed=None).depth_m
    fy, cy = SMALL.K[1, 1], SMALL.K[1, 2]
    rows = np.arange(SMALL.height)[:, None]
    plane = np.where(rows > cy + 2, 1.65 * fy / np.maximum(rows - cy, 1e-9), 0)
    # the bottom rows' centre (nothing parked in the camera's lane within 6 m) is road
    centre = slice(SMALL.width // 2 - 10, SMALL.width // 2 + 10)
    assert np.allclose(
        depth[-6:, centre], np.broadcast_to(plane[-6:], (6, SMALL.width))[:, centre], rtol=1e-4
    )
    assert (depth[0] == 0).any()  # sky


def _stereo_pair(camera: PinholeCamera):
    """A noise-free simulated stereo pair of one street and the right camera's pose."""
    scene = random_scene(11)
    street_T_left = np.eye(4)
    street_T_left[:3, 3] = (scene.ego_x_m, -1.65, 0.0)
    left_T_right = np.eye(4)
    left_T_right[0, 3] = camera.baseline_m
    left = render(scene, camera, street_T_left, noise_seed=None)
    right = render(scene, camera, street_T_left @ left_T_right, noise_seed=None)
    return left, right, left_T_right


def test_simulated_stereo_pair_agrees_with_its_depth(tmp_path: Path) -> None:
    """The right image warped into the left by the left's true depth matches it."""
    camera = kitti_camera().resized(621, 188)
    left, right, _ = _stereo_pair(camera)
    disparity = camera.K[0, 0] * camera.baseline_m / np.maximum(left.depth_m, 1e-6)
    u = (np.arange(camera.width)[None, :] - disparity).astype(np.float32)
    v = np.broadcast_to(np.arange(camera.height, dtype=np.float32)[:, None], u.shape)
    warped = cv2.remap(right.image.astype(np.float32), u, np.ascontiguousarray(v), cv2.INTER_LINEAR)
    seen = (left.depth_m > 0) & (u > 1)
    error = np.abs(warped - left.image).mean(axis=2)[seen]
    unwarped = np.abs(right.image.astype(np.float32) - left.image).mean(axis=2)[seen]
    assert np.median(error) < 1.0 and np.mean(error) < 0.3 * np.mean(unwarped)


def test_simulate_command_writes_kittis_layout(tmp_path: Path) -> None:
    out = tmp_path / "drive"
    result = CliRunner().invoke(
        app,
        [
            "depth",
            "simulate",
            str(out),
            "--frames",
            "2",
            "--stereo",
            "--seed",
            "3",
            "--width",
            "160",
            "--height",
            "48",
        ],
    )
    assert result.exit_code == 0, result.output
    drive = read_drive(out)
    assert drive.names == ("0000000000", "0000000001") and drive.right is not None
    assert drive.camera.width == 160 and drive.camera.K[0, 0] == pytest.approx(
        721.5377 * 160 / 1242
    )
    calib = json.loads((out / "calib.json").read_text())
    assert calib["baseline_m"] == pytest.approx(0.5327)
    # poses: the first is the identity; the camera moves forward along its z (or stands still)
    assert np.allclose(drive.poses[0], np.eye(4))
    assert drive.poses[1][2, 3] >= 0 and abs(drive.poses[1][0, 3]) < 0.2
    assert cv2.imread(str(drive.left[1])).shape == (48, 160, 3)
    depth = read_depth_png(drive.depth[1])
    assert depth.shape == (48, 160) and (depth > 0).mean() > 0.4


def test_eval_command_writes_the_contract(tmp_path: Path) -> None:
    gt, pred = tmp_path / "gt", tmp_path / "pred"
    truth = np.full((20, 30), 10.0)
    for k in range(3):
        write_depth_png(gt / f"{k:06d}.png", truth)
    write_depth_png(pred / "000000.png", truth * 1.1)
    write_depth_png(pred / "000001.png", truth)
    cv2.imwrite(str(pred / "000001.color.png"), np.zeros((20, 30, 3), np.uint8))
    out = tmp_path / "eval.json"
    refused = CliRunner().invoke(
        app, ["depth", "eval", str(pred), str(gt), "--crop", "none", "-o", str(out)]
    )
    assert refused.exit_code == 2 and "1 ground-truth PNGs" in refused.output
    assert not out.exists()  # nothing written for folders that do not match
    write_depth_png(pred / "000009.png", truth)
    refused = CliRunner().invoke(
        app, ["depth", "eval", str(pred), str(gt), "--crop", "none", "-o", str(out)]
    )
    assert "1 predictions in" in refused.output and "no ground truth" in refused.output
    (pred / "000009.png").unlink()
    result = CliRunner().invoke(
        app, ["depth", "eval", str(pred), str(gt), "--crop", "none", "--partial", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert set(data["metrics"]) == {
        "abs_rel",
        "sq_rel",
        "rmse",
        "rmse_log",
        "delta1",
        "delta2",
        "delta3",
    }
    assert [i["name"] for i in data["images"]] == ["000000", "000001"] and data["missing"] == [
        "000002"
    ]
    assert data["metrics"]["abs_rel"] == pytest.approx(0.05, abs=1e-3)
    assert "WARNING, --partial: 1 ground-truth PNGs" in result.output
    refused = CliRunner().invoke(app, ["depth", "eval", str(tmp_path), str(gt), "-o", str(out)])
    assert refused.exit_code == 2 and "no prediction" in refused.output
    refused = CliRunner().invoke(
        app, ["depth", "eval", str(pred), str(gt), "--crop", "middle", "-o", str(out)]
    )
    assert refused.exit_code == 2 and "--crop 'middle'" in refused.output


def test_warp_by_true_depth_reproduces_the_left_image() -> None:
    """The photometric loss's warp: the simulated right image sampled where the left's
    pixels land by their true depth is the left image (torch, as training uses it)."""
    import torch

    from services.depth.losses import photometric_error, ssim, warp

    camera = kitti_camera().resized(320, 96)
    left, right, left_T_right = _stereo_pair(camera)

    def tensor(image: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(image.transpose(2, 0, 1)[None].astype(np.float32) / 255)

    depth = torch.from_numpy(np.where(left.depth_m > 0, left.depth_m, 1000.0)[None, None])
    K = torch.from_numpy(camera.K[None].astype(np.float32))
    right_T_left = torch.from_numpy(np.linalg.inv(left_T_right)[None].astype(np.float32))
    warped = warp(tensor(right.image), depth, K, right_T_left)
    seen = torch.from_numpy((left.depth_m > 0)[None, None]) & (torch.arange(320) > 12)
    error = photometric_error(warped, tensor(left.image))[seen]
    unwarped = photometric_error(tensor(right.image), tensor(left.image))[seen]
    assert error.median() < 0.02 and error.mean() < 0.4 * unwarped.mean()
    assert torch.allclose(ssim(tensor(left.image), tensor(left.image)), torch.ones(1), atol=1e-4)


def test_student_is_the_thesiss_size_and_its_onnx_matches_torch(tmp_path: Path) -> None:
    import torch

    from services.depth.export import export_depth_model
    from services.depth.models import DepthModel
    from services.depth.nets import Student, parameters

    torch.manual_seed(0)
    student = Student().eval()
    assert 2_600_000 < parameters(student) <= 2_700_000  # the thesis's: 2 643 281
    image = (np.random.default_rng(0).random((1, 64, 128, 3)) * 255).astype(np.uint8)
    path = tmp_path / "student.onnx"
    difference = export_depth_model(
        student, path, width=128, height=64, architecture="deeplabv3plus-mobilenetv2"
    )
    assert difference < 1e-3
    model = DepthModel(path)
    with torch.no_grad():
        expected = student(
            torch.from_numpy(image.transpose(0, 3, 1, 2).astype(np.float32) / 255)
        ).numpy()[:, 0]
    got = model.predict(image).depth_m
    assert got.shape == (1, 64, 128) and np.allclose(got, expected, rtol=1e-3)
    assert model.spec.output_kind == "depth" and model.spec.metadata["parameters"] == parameters(
        student
    )


def test_someone_elses_onnx_with_a_spec_beside_it(tmp_path: Path) -> None:
    """A Monodepth2-like model answering sigmoid disparity, BGR in 0–255 with a mean, NHWC:
    read by its side-car JSON and turned into metres."""
    import torch

    from services.depth.models import DepthModel
    from services.lib.nn.onnx_io import export_onnx

    class Disparity(torch.nn.Module):
        def forward(self, bgr: torch.Tensor) -> torch.Tensor:  # (N, H, W, 3) → (N, H, W, 1)
            return torch.sigmoid(bgr[..., :1] / 100.0)

    path = tmp_path / "theirs.onnx"
    example = np.zeros((1, 8, 16, 3), np.float32)
    export_onnx(Disparity(), example, path, {}, input_name="image", output_name="disp")
    # export_onnx stamps vista's metadata; someone else's file has none
    import onnx

    proto = onnx.load_model(str(path))
    del proto.metadata_props[:]
    onnx.save_model(proto, str(path))
    with pytest.raises(ValueError, match="needs its spec"):
        DepthModel(path)
    spec = {
        "input": {
            "width": 16,
            "height": 8,
            "range": 255,
            "mean": [10, 0, 0],
            "channels": "BGR",
            "layout": "NHWC",
        },
        "output": {"kind": "sigmoid_disparity", "min_depth_m": 0.1, "max_depth_m": 100},
    }
    path.with_suffix(".json").write_text(json.dumps(spec))
    model = DepthModel(path)
    image = np.zeros((1, 8, 16, 3), np.uint8)
    image[..., 2] = 110  # blue in RGB is the model's first (B) channel: (110 − 10) / 100 = 1
    sigmoid = 1 / (1 + math.exp(-1.0))
    expected = 1 / (1 / 100 + (1 / 0.1 - 1 / 100) * sigmoid)
    assert np.allclose(model.predict(image).depth_m, expected, rtol=1e-5)
    stamped = tmp_path / "stamped.onnx"
    result = CliRunner().invoke(app, ["depth", "import", str(path), "-o", str(stamped)])
    assert result.exit_code == 0, result.output
    from services.lib.nn.onnx_io import read_model

    assert read_model(stamped).metadata["output"]["kind"] == "sigmoid_disparity"
    assert np.allclose(DepthModel(stamped).predict(image).depth_m, expected, rtol=1e-5)
    spec["output"]["kind"] = "inverse"
    path.with_suffix(".json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match="output.kind 'inverse'"):
        DepthModel(path)
    refused = CliRunner().invoke(app, ["depth", "import", str(path), "-o", str(stamped)])
    assert refused.exit_code == 2 and "output.kind 'inverse'" in refused.output


def test_drive_archives_unpack_to_kittis_layout_and_refuse_the_unsafe(tmp_path: Path) -> None:
    import tarfile
    import zipfile

    from services.depth.drive_archive import extract_drive, inspect_drive
    from services.lib.archive import ArchiveError
    from tests.depthfiles import pack_drive, small_drive

    folder = small_drive(tmp_path / "drive", frames=2)
    packed = pack_drive(folder, tmp_path / "drive.tar.gz")
    found = inspect_drive(packed)
    assert (found.frames, found.stereo, found.depth, found.poses) == (2, True, True, True)
    assert found.media_type == "application/gzip"
    extract_drive(packed, tmp_path / "out")
    assert read_drive(tmp_path / "out").names == ("0000000000", "0000000001")
    # a raw-style zip under a top folder, with a member trying to climb out
    raw = tmp_path / "raw.zip"
    with zipfile.ZipFile(raw, "w") as archive:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                relative = path.relative_to(folder)
                inside = f"2011_09_26_drive_0001_sync/{relative}"
                if relative.parts[0] == "image_02":
                    inside = f"2011_09_26_drive_0001_sync/image_02/data/{relative.name}"
                archive.write(path, inside)
        archive.writestr("2011_09_26_drive_0001_sync/image_02/../../../evil.png", b"x")
        scan = np.zeros((5, 4), "<f4").tobytes()
        for name in ("0000000000", "0000000001"):  # raw's LiDAR layout
            archive.writestr(f"2011_09_26_drive_0001_sync/velodyne_points/data/{name}.bin", scan)
        archive.writestr("2011_09_26_drive_0001_sync/calib_velo_to_cam.txt", "R: 1 0 0\n")
    assert inspect_drive(raw).scans
    extract_drive(raw, tmp_path / "raw")
    assert len(list((tmp_path / "raw" / "image_02").glob("*.png"))) == 2
    assert read_drive(tmp_path / "raw").velodyne == (
        tmp_path / "raw" / "velodyne" / "0000000000.bin",
        tmp_path / "raw" / "velodyne" / "0000000001.bin",
    )
    assert (tmp_path / "raw" / "calib_velo_to_cam.txt").is_file()
    assert not (tmp_path / "evil.png").exists() and not (tmp_path.parent / "evil.png").exists()
    bare = tmp_path / "bare.tar"
    with tarfile.open(bare, "w") as archive:
        archive.add(folder / "image_02", arcname="image_02")
    with pytest.raises(ArchiveError, match="no calib.json"):
        inspect_drive(bare)
    (tmp_path / "junk.tar").write_bytes(b"not an archive at all")
    with pytest.raises(ArchiveError, match="not a zip or tar"):
        inspect_drive(tmp_path / "junk.tar")


def test_a_tiny_distillation_end_to_end(tmp_path: Path) -> None:
    """A teacher trained on four simulated drives, a student distilled from it by each
    method: the student moves towards the teacher, and its int8 copy stays close to it."""
    import torch

    from services.depth.data import load_frames
    from services.depth.distill import agreement, distill, teacher_targets
    from services.depth.export import export_depth_model
    from services.depth.models import DepthModel
    from services.depth.nets import Student
    from services.depth.quantize import quantize_int8
    from services.depth.teacher import train_teacher
    from services.depth.training import DepthTrainConfig
    from tests.depthfiles import small_drive

    drives = [small_drive(tmp_path / f"d{k}", seed=k) for k in range(4)]
    frames = load_frames(drives, 128, 64)
    config = DepthTrainConfig(
        epochs=2, batch=3, learning_rate=1e-3, threads=2, device="cpu", val_fraction=0.25
    )
    teacher = train_teacher(frames, "depth", config)
    assert teacher.val_abs_rel is not None and teacher.fit.best_epoch >= 1
    teacher_path = tmp_path / "teacher.onnx"
    export_depth_model(
        teacher.model,
        teacher_path,
        width=128,
        height=64,
        architecture="monodepth2-resnet18",
        features=True,
    )
    model = DepthModel(teacher_path)
    assert model.feature_names == ("encoder", "decoder")
    targets = teacher_targets(model, frames, features=True)
    assert targets.depth_m.shape == (12, 2, 64, 128) and set(targets.features) == {
        "encoder",
        "decoder",
    }
    torch.manual_seed(0)
    untrained = agreement(Student().eval(), frames, targets, np.arange(len(frames)))
    for method in ("thesis", "vista"):
        result = distill(model, frames, method, replace(config, epochs=10), targets=targets)
        assert result.val_abs_rel_to_teacher < 0.85 * untrained, (
            method,
            result.val_abs_rel_to_teacher,
            untrained,
        )
    assert result.hints == ("encoder", "decoder") and result.photometric == "stereo"
    student_path = tmp_path / "student.onnx"
    export_depth_model(
        result.model, student_path, width=128, height=64, architecture="deeplabv3plus-mobilenetv2"
    )
    fp32 = DepthModel(student_path)
    images = frames.images.transpose(0, 2, 3, 1)
    int8 = DepthModel(quantize_int8(fp32, images, tmp_path / "student.int8.onnx"))
    assert int8.spec.metadata["quantization"]["calibration_images"] == 12
    a, b = fp32.predict(images).depth_m, int8.predict(images).depth_m
    assert np.median(np.abs(a - b) / a) < 0.05  # int8 costs a few per cent at most


KITTI_HELD_OUT = KITTI_RAW.parent / "kitti-object-testing-sample"


@pytest.mark.skipif(not KITTI_RAW.is_dir(), reason="the shared KITTI sample is not here")
def test_lidar_depth_is_kittis_projection_at_any_size(tmp_path: Path) -> None:
    """The scans through calib.json give the drive's own depth PNGs pixel for pixel; KITTI
    raw's text calibration gives the same; at the training size the nearest return wins."""
    from services.depth.data import load_frames
    from services.depth.lidar import lidar_depth, read_lidar_calibration
    from services.lib.kitti import read_velodyne

    drive = read_drive(KITTI_RAW)
    assert drive.velodyne is not None and all(drive.velodyne)
    calibration = read_lidar_calibration(KITTI_RAW)
    points = read_velodyne(drive.velodyne[0])
    truth = read_depth_png(drive.depth[0])
    mine = lidar_depth(points, calibration, (1242, 375), (1242, 375))
    assert ((mine > 0) == (truth > 0)).all()
    assert np.abs(mine - truth).max() < 2 / 256  # the PNG stores 1/256 m steps
    data = json.loads((KITTI_RAW / "calib.json").read_text())
    velo_T = np.asarray(data["cam0_T_velo"])
    text = tmp_path / "text"
    text.mkdir()
    (text / "calib_velo_to_cam.txt").write_text(
        "R: " + " ".join(map(str, velo_T[:3, :3].ravel())) + "\n"
        "T: " + " ".join(map(str, velo_T[:3, 3])) + "\n"
    )
    (text / "calib_cam_to_cam.txt").write_text(
        "R_rect_00: " + " ".join(map(str, np.ravel(data["R_rect_00"]))) + "\n"
        "P_rect_02: " + " ".join(map(str, np.ravel(data["P_rect_02"]))) + "\n"
    )
    again = read_lidar_calibration(text)
    assert np.allclose(again.rect_T_velo, calibration.rect_T_velo)
    small = lidar_depth(points, calibration, (1242, 375), (320, 96))
    assert 2_000 < (small > 0).sum() < 320 * 96 and small[small > 0].min() > 1
    frames = load_frames([KITTI_RAW], 320, 96, lidar=True)
    assert frames.depth_m.shape == (40, 1, 96, 320) and np.array_equal(frames.depth_m[0, 0], small)
    with pytest.raises(ValueError, match="no LiDAR calibration"):
        read_lidar_calibration(tmp_path / "nowhere")


def test_a_teacher_onnx_loads_for_fine_tuning(tmp_path: Path) -> None:
    """A trained teacher's ONNX (batch norms folded by the export) back in torch answers as
    the original did, and a student file is refused as a starting teacher."""
    import torch

    from services.depth.export import export_depth_model
    from services.depth.nets import Student, Teacher
    from services.depth.teacher import load_teacher

    torch.manual_seed(0)
    teacher = Teacher()
    for layer in teacher.modules():
        if isinstance(layer, torch.nn.BatchNorm2d):
            layer.running_mean.uniform_(-0.2, 0.2)
            layer.running_var.uniform_(0.5, 2.0)
            layer.weight.data.uniform_(0.5, 1.5)
            layer.bias.data.uniform_(-0.2, 0.2)
    teacher.eval()
    path = tmp_path / "teacher.onnx"
    export_depth_model(
        teacher, path, width=64, height=64, architecture="monodepth2-resnet18", features=True
    )
    loaded = load_teacher(path).eval()
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in loaded.modules())
    x = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        assert torch.allclose(loaded(x), teacher(x), rtol=1e-4, atol=1e-5)
    student = tmp_path / "student.onnx"
    export_depth_model(
        Student().eval(), student, width=64, height=64, architecture="deeplabv3plus-mobilenetv2"
    )
    with pytest.raises(ValueError, match="fine-tuning starts from a teacher"):
        load_teacher(student)


def test_weights_stored_in_int8_are_a_quarter_and_compute_as_before(tmp_path: Path) -> None:
    from services.depth.export import export_depth_model
    from services.depth.models import DepthModel
    from services.depth.nets import Student
    from services.lib.nn.onnx_io import store_weights_int8

    path = tmp_path / "student.onnx"
    export_depth_model(
        Student().eval(), path, width=128, height=64, architecture="deeplabv3plus-mobilenetv2"
    )
    small = store_weights_int8(path, tmp_path / "small.onnx")
    assert small.stat().st_size < 0.3 * path.stat().st_size
    fp32, int8 = DepthModel(path), DepthModel(small)
    assert int8.spec.metadata == fp32.spec.metadata
    images = np.random.default_rng(0).integers(0, 255, (2, 64, 128, 3), dtype=np.uint8)
    a, b = fp32.predict(images).depth_m, int8.predict(images).depth_m
    assert np.median(np.abs(a - b) / a) < 0.01


def test_the_preview_has_a_colour_bar_in_metres() -> None:
    from services.depth.predict import colour_bar, colour_preview

    depth = np.tile(np.linspace(60, 3, 96)[:, None], (1, 320)).astype(np.float32)
    preview = colour_preview(depth)
    assert preview.shape[0] > 96 and preview.shape[1] == 320
    bar = colour_bar(320, 1 / 3)
    # far on the left (dark), near on the right (bright)
    assert bar[0, -1].sum() > bar[0, 0].sum() + 300


@pytest.mark.skipif(not KITTI_HELD_OUT.is_dir(), reason="the shared KITTI sample is not here")
def test_build_default_at_a_tiny_scale(tmp_path: Path) -> None:
    """The shipped model's recipe end to end on three simulated drives, one epoch a stage,
    64 × 64: simulated teacher, LiDAR adaptation on the real drive, student, int8 weights,
    the held-out score and the licence in the metadata; the predict command uses it."""
    from services.depth.default_model import build_default_model
    from services.depth.kinds import BuildSettings
    from services.lib.nn.onnx_io import read_model

    out = tmp_path / "depth.onnx"
    settings = BuildSettings(
        sim_drives=3,
        teacher_epochs=1,
        adapt_epochs=1,
        adapt_sim_drives=1,
        student_epochs=1,
        student_sim_drives=2,
        batch=4,
        width=64,
        height=64,
    )
    metadata = build_default_model(out, work=tmp_path / "work", settings=settings)
    assert read_model(out).metadata == metadata
    assert "CC BY-NC-SA 3.0" in metadata["licence"]
    assert metadata["training_data"]["real_frames"] == 40
    validation = metadata["validation"]
    assert len(validation["frames"]) == 10 and validation["shipped"]["frames"] == 10
    assert 0 < validation["shipped"]["abs_rel"] < 2
    adapted = read_model(tmp_path / "work" / "teacher-lidar.onnx").metadata["training"]
    # every real frame trains; the simulated drive validates
    assert adapted["adapted_from"] == "teacher.onnx" and adapted["frames"] == {
        "train": 40,
        "val": 3,
    }
    result = CliRunner().invoke(
        app,
        ["depth", "predict", str(KITTI_HELD_OUT / "image_2"), "-o", str(tmp_path / "pred"),
         "--model", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    evaluation = CliRunner().invoke(
        app,
        ["depth", "eval", str(tmp_path / "pred"), str(KITTI_HELD_OUT / "depth"),
         "--median-scaling", "-o", str(tmp_path / "eval.json")],
    )  # fmt: skip
    assert evaluation.exit_code == 0, evaluation.output
    scored = json.loads((tmp_path / "eval.json").read_text())["metrics"]["abs_rel"]
    assert scored == pytest.approx(validation["shipped"]["abs_rel"], rel=0.02)


@pytest.mark.skipif(not KITTI_HELD_OUT.is_dir(), reason="the shared KITTI sample is not here")
def test_predict_uses_the_shipped_model(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A new user's first real images: no model given, the shipped one answers (its
    metadata says where it comes from and its licence); without one, the error says how to
    get one."""
    import services.depth.models as models
    from services.lib.nn.onnx_io import read_model

    shipped = read_model(models.PACKAGED).metadata
    assert "CC BY-NC-SA 3.0" in shipped["licence"] and shipped["validation"]["shipped"]["frames"]
    assert models.PACKAGED.stat().st_size <= 5_000_000
    images = tmp_path / "images"
    images.mkdir()
    for name in ("000000.png", "000001.png"):
        (images / name).write_bytes((KITTI_HELD_OUT / "image_2" / name).read_bytes())
    result = CliRunner().invoke(app, ["depth", "predict", str(images), "-o", str(tmp_path / "p")])
    assert result.exit_code == 0, result.output
    depth = read_depth_png(tmp_path / "p" / "000000.png")
    preview = cv2.imread(str(tmp_path / "p" / "000000.color.png"))
    assert depth.shape == (375, 1242) and preview.shape[0] > 375  # the colour bar below
    assert (tmp_path / "p" / "000000.ply").stat().st_size > 1000  # clouds, as the job's default
    raw = np.full((1, 1, 4, 4), 0.5, np.float32)
    raw[0, 0, 0, 0] = np.nan  # an int8 model out of its calibration's range answered so
    with pytest.raises(ValueError, match="no valid depth .* 6.2% of the pixels"):
        models.DepthModel(models.PACKAGED).to_depth(raw)
    monkeypatch.setattr(models, "PACKAGED", tmp_path / "none.onnx")
    result = CliRunner().invoke(app, ["depth", "predict", str(images), "-o", str(tmp_path / "q")])
    assert result.exit_code == 2 and "vista depth build-default" in result.output


def test_predict_reads_a_raw_drive_as_the_job_does(tmp_path: Path) -> None:
    """`vista depth predict` and the `depth.predict` job read a folder alike
    (``predict.image_set``): a KITTI raw drive's ``image_02/data/``, placed by the
    calibration in its date folder; several sets each go to their own folder."""
    from services.depth.kinds import PredictParams
    from services.depth.predict import image_set, predict_depth
    from services.lib.pointcloud.ply import read_ply
    from tests.depthfiles import small_drive, tiny_depth_model

    drive = small_drive(tmp_path / "2011_09_26" / "drive", frames=2, stereo=False)
    (drive / "image_02" / "data").mkdir()
    for image in sorted((drive / "image_02").glob("*.png")):
        image.rename(drive / "image_02" / "data" / image.name)
    (drive / "calib.json").rename(drive.parent / "calib.json")
    found = image_set(drive)
    assert [p.name for p in found.images] == ["0000000000.png", "0000000001.png"]
    assert found.calibration == drive
    model = tiny_depth_model(tmp_path / "tiny.onnx")
    out = tmp_path / "cli"
    result = CliRunner().invoke(
        app, ["depth", "predict", str(drive), "-o", str(out), "--model", str(model), "--int8"]
    )
    assert result.exit_code == 0, result.output
    assert "wrote 2 depth maps" in result.output and "int8" in result.output
    assert (out / "model.int8.onnx").is_file()
    cloud = read_ply(out / "0000000001.ply")
    assert cloud.grid_shape == (64, 128)
    both = predict_depth([found, image_set(drive)], PredictParams(), tmp_path / "core", model=model)
    assert [p.depth_path.parent.name for p in both.images] == ["set-0"] * 2 + ["set-1"] * 2
    assert both.architecture == "tiny" and (both.width, both.height) == (64, 32)
    assert np.array_equal(
        read_depth_png(both.images[1].depth_path), read_depth_png(both.images[3].depth_path)
    )
    refused = CliRunner().invoke(app, ["depth", "predict", str(tmp_path), "-o", str(out)])
    assert refused.exit_code == 2 and "no PNG or JPEG images" in refused.output


def test_train_command_and_its_old_spellings(tmp_path: Path) -> None:
    """`vista depth train` trains what the `depth.train` job would, `--network` choosing the
    teacher or the student; `train-teacher` and `distill` still work, hidden."""
    from services.depth.cli import depth_app
    from services.lib.nn.onnx_io import read_model
    from tests.depthfiles import small_drive

    drives = [str(small_drive(tmp_path / f"d{k}", seed=k)) for k in range(2)]
    small = ["--width", "64", "--height", "64", "--epochs", "1", "--batch", "2"]
    small += ["--device", "cpu", "--threads", "2"]
    teacher = tmp_path / "teacher.onnx"
    old = ["depth", "train-teacher", *drives, "-o", str(teacher), *small]
    result = CliRunner().invoke(app, old)
    assert result.exit_code == 0, result.output
    assert "monodepth2-resnet18: val_abs_rel" in result.output
    training = read_model(teacher).metadata["training"]
    assert training["supervision"] == "depth" and training["inputs"] == drives
    student = tmp_path / "student.onnx"
    new = ["depth", "train", *drives, "--model", str(teacher), "-o", str(student), *small]
    result = CliRunner().invoke(app, new)
    assert result.exit_code == 0, result.output
    training = read_model(student).metadata["training"]
    assert training["teacher"] == "teacher.onnx" and training["method"] == "vista"
    refused = CliRunner().invoke(app, ["depth", "train", *drives, "-o", str(student), *small])
    assert refused.exit_code == 2 and "network student needs its teacher" in refused.output
    missing = tmp_path / "none.onnx"
    old = ["depth", "distill", *drives, "--teacher", str(missing), "-o", str(student), *small]
    refused = CliRunner().invoke(app, old)
    assert refused.exit_code == 2 and f"{missing}: no such file" in refused.output
    shown = {c.name for c in depth_app.registered_commands if not c.hidden}
    assert {"train", "predict", "simulate", "bench", "build-default"} <= shown
    assert not shown & {"train-teacher", "distill"}


def test_simulate_and_bench_are_depth_verbs(tmp_path: Path) -> None:
    """`vista depth simulate` and `vista depth bench`; the old `vista simulate depth` and
    `vista bench depth` kept as hidden aliases."""
    runner = CliRunner()
    assert runner.invoke(app, ["depth", "bench", "--help"]).exit_code == 0
    for old, new in (
        (["simulate", "depth"], "depth simulate"),
        (["bench", "depth"], "depth bench"),
    ):
        result = runner.invoke(app, [*old, "--help"])
        assert result.exit_code == 0 and f"Alias of `vista {new}`" in result.output
    result = runner.invoke(
        app, ["simulate", "depth", str(tmp_path / "d"), "--frames", "1", "--width", "64",
              "--height", "32"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert read_drive(tmp_path / "d").names == ("0000000000",)
