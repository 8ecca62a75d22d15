"""The tracking service on real KITTI scans (``../shared/data``): the shipped detector on the
labelled drive it never saw, fine-tuning it on a few labelled scans, its build recipe at a
tiny scale, ground-truth sampling, the drive labelled every other frame as tracklets, the
geometric detector's shape score, and the defaults tracking the drive's cars."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from services.lib import kitti
from services.tracking.bench_real import linked_object_folder
from supervisor.cli import app
from tests.lidarfiles import REAL_LABELLED_DRIVE, REAL_OBJECTS

pytestmark = pytest.mark.skipif(
    not (REAL_OBJECTS.is_dir() and REAL_LABELLED_DRIVE.is_dir()),
    reason="the shared KITTI sample is not here",
)


def test_a_drive_labelled_every_other_frame_links_its_cars_into_tracklets() -> None:
    """KITTI object labels of frames 2, 4 … 20 with no track ids: a car keeps its type and
    h w l, so seven cars; a tracklet runs through every frame from its first labelled one
    to its last, the odd frames' boxes unknown."""
    from services.tracking.sequence import open_sequence, tracklets

    drive = open_sequence(REAL_LABELLED_DRIVE)
    assert drive.label_step == 2
    cars = tracklets(drive, ("Car",), 2)
    assert len(cars) == 7
    longest = max(cars, key=lambda t: len(t.frames))
    assert longest.frames == list(range(2, 21)) and longest.labelled.sum() == 10
    assert not longest.labelled[1] and np.isnan(longest.boxes[1]).all()
    sizes = {tuple(np.round(t.boxes[t.labelled][0, 3:6], 2)) for t in cars}
    assert len(sizes) == 7  # one car per size: none linked to another's


def test_pasted_cars_keep_their_range_and_hide_what_is_behind_them() -> None:
    """Cars cut from one real scan pasted into another: each keeps its distance from the
    sensor (turned about it), stands clear of the labelled objects, and the returns its
    body shadows are gone."""
    from services.lib.boxes import bev_iou, inside
    from services.tracking.datasets import labelled_scans
    from services.tracking.detector_training import labels_speak
    from services.tracking.ground import estimate_ground
    from services.tracking.paste import _range_bins, cut_cars, paste_cars

    donor, background = labelled_scans([REAL_OBJECTS])[10], labelled_scans([REAL_OBJECTS])[3]
    cars = cut_cars(kitti.read_velodyne(donor.path), donor.cars)
    assert len(cars) >= 4 and all(len(c.points) >= 20 for c in cars)
    points = kitti.read_velodyne(background.path)
    points[:, 3] = -1.0  # the background's returns, marked
    pasted_points, pasted = paste_cars(
        points, background.objects, estimate_ground(points), cars, np.random.default_rng(1), 8,
        lambda centres: labels_speak(centres[:, :2], background),
    )  # fmt: skip
    assert len(pasted) >= 2
    ranges = [np.hypot(*c.box[:2]) for c in cars]
    for box in pasted:
        assert min(abs(np.hypot(*box[:2]) - r) for r in ranges) < 0.01
        assert inside(pasted_points, box).sum() >= 10
        assert labels_speak(box[None, :2], background)[0]
    assert (bev_iou(background.objects[:, None], pasted[None]) == 0).all()
    # no background return remains behind a pasted car's body, bin by bin of the range image
    old = pasted_points[:, 3] == -1.0
    car_bins, car_range = _range_bins(pasted_points[~old])
    nearest = {}
    for b, r in zip(car_bins.tolist(), car_range.tolist(), strict=True):
        nearest[b] = min(r, nearest.get(b, np.inf))
    old_bins, old_range = _range_bins(pasted_points[old])
    shadowed = [
        r > nearest[b]
        for b, r in zip(old_bins.tolist(), old_range.tolist(), strict=True)
        if b in nearest
    ]
    assert not any(shadowed)
    assert old.sum() < len(points)  # what the cars hide is gone


def test_the_shipped_detector_finds_the_cars_of_a_real_drive_it_never_saw() -> None:
    """vista's default detector on the labelled drive held out of its training: recall of
    the cars within 40 m and precision in the camera's view as its metadata reports them;
    its metadata names the data, the seed and KITTI's licence."""
    from services.lib.nn.onnx_io import read_model
    from services.tracking.bench_real import detection_scores
    from services.tracking.datasets import labelled_scans
    from services.tracking.detect_learned import DEFAULT_MODEL, LearnedDetector

    assert DEFAULT_MODEL.stat().st_size <= 5 << 20
    metadata = read_model(DEFAULT_MODEL).metadata
    training = metadata["training"]
    assert "CC BY-NC-SA 3.0" in training["licence"] and training["seed"] == 0
    assert training["data"] == ["../shared/data/kitti-object-sample"]
    assert training["command"].startswith(
        (
            "vista track train default-detector",
            "vista tracking train default-detector",
            "vista tracking build-default",
        )
    )
    held_out = metadata["validation"]
    assert held_out["held_out"] and held_out["scan_names"][0].startswith(REAL_LABELLED_DRIVE.name)
    assert training["validated_on"] == ["../shared/data/kitti-raw-2011_09_26_drive_0048"]
    scores = detection_scores(LearnedDetector(DEFAULT_MODEL), labelled_scans([REAL_LABELLED_DRIVE]))
    assert scores["recall_near"] >= 0.8 and scores["precision_in_view"] >= 0.7, scores
    assert scores["found_near"] == held_out["found_near"]


def test_fine_tuning_the_shipped_detector_reports_before_and_after(tmp_path: Path) -> None:
    """`vista tracking train --from` on a few labelled scans, validated on others:
    the model starts as the shipped one (the same scores before as the shipped model
    gets), and the metadata holds both scores, the starting model and the licence."""
    from services.lib.nn.onnx_io import read_model
    from services.tracking.datasets import labelled_scans
    from services.tracking.detect_learned import DEFAULT_MODEL

    scans = labelled_scans([REAL_OBJECTS])
    train = linked_object_folder(scans[8:10], tmp_path / "train")
    held = linked_object_folder(scans[10:11], tmp_path / "held")
    out = tmp_path / "mine.onnx"
    done = CliRunner().invoke(
        app,
        [
            "tracking", "train", str(train), "--from", str(DEFAULT_MODEL),
            "--validate", str(held), "--epochs", "1", "--windows", "4", "--batch", "2",
            "--window", "96", "--licence", "KITTI, CC BY-NC-SA 3.0", "-o", str(out),
        ],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    assert "before: 1 scans" in done.output and "after: 1 scans" in done.output
    metadata = read_model(out).metadata
    assert metadata["training"]["fine_tuned_from"]["file"] == "detector.onnx"
    assert metadata["training"]["licence"] == "KITTI, CC BY-NC-SA 3.0"
    before = metadata["validation"]["before_fine_tuning"]
    assert before["cars_near"] == metadata["validation"]["cars_near"] == 7
    refused = CliRunner().invoke(
        app, ["tracking", "train", str(train), "--from", "nowhere.onnx", "-o", str(out)]
    )
    assert refused.exit_code == 2 and "no such model file" in refused.output


def test_the_default_detector_recipe_runs_at_a_tiny_scale(tmp_path: Path) -> None:
    """The shipped model's build (simulate, train on the simulation, fine-tune on the real
    object scans, validate on the held-out drive) with one 3-frame drive and a few windows:
    every step's file is made and the metadata says what the shipped one says."""
    from services.tracking.default_detector import BuildSettings, build_default_detector
    from services.tracking.detector_training import DetectorTrainConfig

    settings = BuildSettings(drives=1, frames=3, tune_epochs=1, tune_windows=2)
    metadata = build_default_detector(
        tmp_path / "work", tmp_path / "detector.onnx", settings=settings,
        base_config=DetectorTrainConfig(epochs=1, batch=2, window_cells=96, windows_per_epoch=2),
        say=lambda message: None,
    )  # fmt: skip
    assert (tmp_path / "work" / "detector-sim.onnx").is_file()
    assert (tmp_path / "detector.onnx").is_file()
    assert metadata["validation"]["held_out"] and metadata["validation"]["cars_near"] == 47
    assert metadata["training"]["fine_tuned_from"]["file"] == "detector-sim.onnx"
    assert "CC BY-NC-SA 3.0" in metadata["training"]["licence"]
    assert metadata["training"]["command"] == (
        "vista tracking build-default --drives 1 --frames 3 --tune-epochs 1 --tune-windows 2 "
        "--seed 0"
    )


def test_the_geometric_detector_scores_a_cars_shape_above_a_hedge_and_a_trunk() -> None:
    """``car_likeness`` on shapes built by hand: a car's smooth sides, roof and sills score
    high; a scattering volume of foliage, a cluster under a canopy and a cluster rising
    past a roof's height score lower."""
    from services.tracking.detect_geometric import car_likeness, surface_variation

    rng = np.random.default_rng(0)
    side = np.column_stack([rng.uniform(0, 4, 600), np.zeros(600), rng.uniform(0.25, 1.0, 600)])
    roof = np.column_stack([rng.uniform(1, 3, 300), rng.uniform(0, 1.6, 300), np.full(300, 1.45)])
    car = np.concatenate([side, roof]) + rng.normal(0, 0.01, (900, 3))
    hedge = rng.uniform([0, 0, 0.3], [3, 1.5, 1.6], (900, 3))
    assert surface_variation(car) < 0.01 < 0.05 < surface_variation(hedge)
    car_score = car_likeness(car[:, 2], 0.0, surface_variation(car))
    assert car_score > 0.9
    assert car_likeness(hedge[:, 2], 0.0, surface_variation(hedge)) < 0.5 * car_score
    assert car_likeness(car[:, 2], 1.0, surface_variation(car)) < 0.3 * car_score  # under a tree
    tall = car.copy()
    tall[:, 2] *= 1.8  # rises to 2.6 m: a wall, a lorry, an embankment
    assert car_likeness(tall[:, 2], 0.0, surface_variation(tall)) < 0.1


def test_the_defaults_track_the_real_drives_cars(tmp_path: Path) -> None:
    """`vista tracking track` with its defaults (geometric tracker, the shipped detector,
    adaptive resets, ego motion from the scans: the drive has no poses) on each car of the
    real labelled drive, and `vista tracking eval` on the labelled frames."""
    runner = CliRunner()
    runs = []
    for track_id in (3, 4, 5, 6, 7):
        out = tmp_path / f"t{track_id}.json"
        done = runner.invoke(
            app,
            [
                "tracking",
                "track",
                str(REAL_LABELLED_DRIVE),
                "--track-id",
                str(track_id),
                "-o",
                str(out),
            ],
        )
        assert done.exit_code == 0, done.output
        document = json.loads(out.read_text())
        assert document["reset"].startswith("adaptive") and document["detector"] == "learned"
        runs.append(str(out))
    evaluated = tmp_path / "eval.json"
    done = runner.invoke(
        app, ["tracking", "eval", str(REAL_LABELLED_DRIVE), *runs, "-o", str(evaluated)]
    )
    assert done.exit_code == 0, done.output
    scores = json.loads(evaluated.read_text())
    assert scores["ope"]["frames"] == 47 and all(r["unlabelled_frames"] > 0 for r in scores["runs"])
    assert scores["ope"]["success"] >= 70 and scores["ope"]["precision"] >= 85, scores["ope"]


def _tar(folder: Path, out: Path, names: list[str]) -> Path:
    """``names`` (files or folders) of ``folder`` as a plain tar under a top folder."""
    import tarfile

    with tarfile.open(out, "w") as tar:
        for name in names:
            tar.add(folder / name, arcname=f"{folder.name}/{name}")
    return out


def test_a_labelled_raw_drive_uploaded_as_a_lidar_archive_keeps_its_labels(tmp_path) -> None:
    """Drive 0048 packed with its per-frame label_2/ (as the CLI reads the folder): the
    archive's labels are linked into the same tracks the CLI finds; a drive with vista's
    calib.json (0052's layout) is taken too."""
    from services.tracking.lidar_archive import extract_lidar, inspect_lidar
    from services.tracking.sequence import open_sequence

    packed = _tar(REAL_LABELLED_DRIVE, tmp_path / "0048.tar", ["velodyne", "label_2", "calib.txt"])
    found = inspect_lidar(packed)
    cli = open_sequence(REAL_LABELLED_DRIVE)
    assert found.frames == len(cli.frames) and found.labels == len(cli.labels)
    assert found.tracks == len(np.unique(cli.labels.track_id[cli.labels.track_id >= 0]))
    assert found.tracks > 0
    extract_lidar(packed, tmp_path / "unpacked")
    unpacked = open_sequence(tmp_path / "unpacked")
    assert np.array_equal(unpacked.labels.track_id, cli.labels.track_id)

    drive = REAL_LABELLED_DRIVE.parent / "kitti-raw-2011_09_26"
    small = tmp_path / "0052"
    (small / "velodyne").mkdir(parents=True)
    for scan in sorted((drive / "velodyne").glob("*.bin"))[:2]:
        (small / "velodyne" / scan.name).write_bytes(scan.read_bytes())
    (small / "calib.json").write_text((drive / "calib.json").read_text())
    with_json = inspect_lidar(_tar(small, tmp_path / "0052.tar", ["velodyne", "calib.json"]))
    assert (with_json.frames, with_json.labels) == (2, 0)
