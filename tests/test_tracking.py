"""3D car tracking on LiDAR: KITTI's formats against the real sample, the simulator's truth,
the overlaps and One-Pass Evaluation against cases computed by hand, each branch (trackers,
detectors, association, resets) against truth at small scale, the commands and the jobs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from services.lib import kitti
from services.lib.boxes import bev_iou, inside, iou_3d
from supervisor.cli import app
from tests.lidarfiles import REAL_DRIVE, REAL_OBJECTS, small_drive

real_data = pytest.mark.skipif(
    not REAL_OBJECTS.is_dir(), reason="the shared KITTI sample is not here"
)


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return small_drive(tmp_path_factory.mktemp("tracking") / "drive")


def _real(scan: int) -> tuple[np.ndarray, kitti.Calibration, kitti.Labels]:
    return (
        kitti.read_velodyne(REAL_OBJECTS / "velodyne" / f"{scan:06d}.bin"),
        kitti.read_calibration(REAL_OBJECTS / "calib" / f"{scan:06d}.txt"),
        kitti.read_object_labels(REAL_OBJECTS / "label_2" / f"{scan:06d}.txt"),
    )


# --- overlaps and One-Pass Evaluation, by hand --------------------------------------------


def test_detection_ratios_carry_their_wilson_interval() -> None:
    from services.tracking.detection_eval import ratio_text, wilson_interval

    assert wilson_interval(8, 10) == pytest.approx((0.490, 0.943), abs=1e-3)  # textbook case
    assert wilson_interval(0, 2) == pytest.approx((0.0, 0.658), abs=1e-3)
    assert wilson_interval(3, 0) is None
    assert "low confidence" in ratio_text(0, 2)  # two cars measure nothing
    assert "low confidence" not in ratio_text(393, 418)
    assert ratio_text(0, 0).startswith("unmeasured")


def test_overlaps_against_cases_computed_by_hand() -> None:
    cube = np.array([0, 0, 0, 1, 1, 1, 0.0])
    assert iou_3d(cube, cube) == pytest.approx(1.0)
    assert iou_3d(cube, cube + [0.5, 0.5, 0, 0, 0, 0, 0]) == pytest.approx(0.25 / 1.75)
    assert iou_3d(cube, cube + [0, 0, 0.5, 0, 0, 0, 0]) == pytest.approx(0.5 / 1.5)
    square = np.array([0, 0, 0, 2, 2, 1, 0.0])
    # a square and itself turned 45°: a regular octagon of area 8(√2 − 1)
    octagon = 8 * (np.sqrt(2) - 1)
    turned = square + [0, 0, 0, 0, 0, 0, np.pi / 4]
    assert bev_iou(square, turned) == pytest.approx(octagon / (8 - octagon))
    assert bev_iou(square, square + [0, 0, 0, 0, 0, 0, np.pi / 2]) == pytest.approx(1.0)
    assert bev_iou(square, square + [3, 0, 0, 0, 0, 0, 0.3]) == 0.0
    car = np.array([10, -2, -0.9, 4.2, 1.8, 1.5, 0.4])
    shifted = car + [0.5 * 4.2 * np.cos(0.4), 0.5 * 4.2 * np.sin(0.4), 0, 0, 0, 0, 0]
    assert iou_3d(car, shifted) == pytest.approx(1 / 3)


def test_one_pass_evaluation_against_a_case_computed_by_hand() -> None:
    """IoUs 1, ½, 0 and centre errors 0, 1, 3 m: the success curve is 1 at 0, ⅔ to 0.5, ⅓
    above; the precision curve ⅓ below 1 m, ⅔ from 1 m — trapezoids give 51.667 and 50.833."""
    from services.tracking.ope import one_pass

    result = one_pass(
        [np.array([1.0, 0.5]), np.array([0.0])], [np.array([0.0, 1.0]), np.array([3.0])]
    )
    assert result.success == pytest.approx(51.6667, abs=1e-3)
    assert result.precision == pytest.approx(50.8333, abs=1e-3)
    assert result.frames == 3 and result.tracklets == 2
    perfect = one_pass([np.ones(5)], [np.zeros(5)])
    assert perfect.success == pytest.approx(100.0) and perfect.precision == pytest.approx(100.0)


# --- KITTI's formats against the real sample ----------------------------------------------


@real_data
def test_real_labels_go_to_the_lidar_and_back_and_project_onto_their_2d_boxes() -> None:
    for scan in range(6):
        points, calibration, labels = _real(scan)
        assert points.shape[1] == 4 and len(points) > 100_000
        objects = labels.select(np.array([t != kitti.DONT_CARE for t in labels.type]))
        boxes = kitti.camera_to_lidar(objects.camera_box, calibration)
        np.testing.assert_allclose(
            kitti.lidar_to_camera(boxes, calibration), objects.camera_box, atol=5e-4
        )
        projected, _ = kitti.image_boxes(boxes, calibration, (1242, 375))
        cars = np.array([t == "Car" for t in objects.type])
        np.testing.assert_allclose(projected[cars], objects.bbox[cars], atol=3.0)
    points, calibration, labels = _real(3)
    car = kitti.camera_to_lidar(labels.of_type("Car").camera_box, calibration)[0]
    assert 600 < inside(points, car).sum() < 800  # the car 13.5 m ahead: 674 returns


@real_data
def test_kitti_files_round_trip(tmp_path: Path) -> None:
    points, calibration, labels = _real(1)
    kitti.write_velodyne(tmp_path / "000001.bin", points)
    np.testing.assert_array_equal(kitti.read_velodyne(tmp_path / "000001.bin"), points)
    kitti.write_calibration(tmp_path / "calib.txt", calibration)
    again = kitti.read_calibration(tmp_path / "calib.txt")
    np.testing.assert_allclose(again.rect_T_velo, calibration.rect_T_velo, atol=1e-12)
    np.testing.assert_allclose(again.P2, calibration.P2)
    text = kitti.format_labels(labels, tracking=False)
    parsed = kitti.parse_labels(text, "label_2", tracking=False)
    np.testing.assert_allclose(parsed.camera_box, labels.camera_box, atol=0.005)
    assert parsed.type == labels.type
    drive = kitti.read_calibration(REAL_DRIVE / "calib.json")
    assert np.allclose(drive.P2[0, 0], 721.5377)


def test_kitti_files_refuse_what_they_are_not(tmp_path: Path) -> None:
    (tmp_path / "odd.bin").write_bytes(b"\0" * 18)
    with pytest.raises(kitti.KittiError, match="not a whole number of points"):
        kitti.read_velodyne(tmp_path / "odd.bin")
    (tmp_path / "calib.txt").write_text("P2: 1 2 3\n")
    with pytest.raises(kitti.KittiError, match="no R0_rect, Tr_velo_to_cam"):
        kitti.read_calibration(tmp_path / "calib.txt")
    with pytest.raises(kitti.KittiError, match="line 1: 4 fields"):
        kitti.parse_labels("0 1 Car 0\n", "label_02.txt", tracking=True)
    with pytest.raises(kitti.KittiError, match="12 finite numbers"):
        kitti.parse_poses("1 0 0 0 0 1 0 0 0 0 1\n", "poses.txt")


# --- the simulator's truth ----------------------------------------------------------------


def test_simulated_labels_hug_their_objects_points(drive: Path) -> None:
    """The followed car (track 0) is labelled in every frame; its box holds its returns
    (within the range noise, 2 cm) — the turning sensor's distortion included: grown by
    0.4 m more (above the road), it gains almost nothing — and the ground sits 1.73 m under
    the sensor."""
    from services.tracking.sequence import open_sequence, tracklets

    sequence = open_sequence(drive)
    lead = next(t for t in tracklets(sequence) if t.track_id == 0)
    assert lead.frames == sequence.frames
    for frame, box in zip(lead.frames, lead.boxes, strict=True):
        points = sequence.points(frame)
        above = points[points[:, 2] > box[2] - box[5] / 2 + 0.25]
        held, grown = inside(above, box, 0.08).sum(), inside(above, box, 0.48).sum()
        assert held > 50 and grown <= 1.03 * held
    points = sequence.points(0)
    road = points[(np.abs(points[:, 1]) < 1.0) & (points[:, 0] > 3.0) & (points[:, 0] < 6.0)]
    assert np.median(road[:, 2]) == pytest.approx(-1.73, abs=0.06)
    labels = sequence.labels
    assert set(labels.type) <= {"Car", "Van", "Truck", "Pedestrian", "Cyclist"}
    boxes = kitti.camera_to_lidar(labels.camera_box, sequence.calibration)
    projected, _ = kitti.image_boxes(boxes, sequence.calibration, (1242, 375))
    np.testing.assert_allclose(projected, labels.bbox, atol=0.05)  # the files keep 6 decimals
    travelled = np.linalg.norm(np.diff(sequence.poses[:, :3, 3], axis=0), axis=1)
    assert (travelled < 2.0).all()  # at most 20 m/s


# --- the branches at small scale ----------------------------------------------------------


def test_geometric_tracker_follows_the_simulated_lead_car(drive: Path) -> None:
    from services.tracking.geometric_tracker import GeometricTracker
    from services.tracking.ope import frame_scores
    from services.tracking.pipeline import track
    from services.tracking.resets import ResetPolicy
    from services.tracking.run import scan_stream
    from services.tracking.sequence import open_sequence, tracklets

    sequence = open_sequence(drive)
    lead = next(t for t in tracklets(sequence) if t.track_id == 0)
    result = track(
        scan_stream(sequence, lead.frames),
        lead.boxes[0],
        GeometricTracker(),
        None,
        ResetPolicy.parse("never"),
    )
    iou, error = frame_scores(result.boxes, lead.boxes)
    assert iou.mean() > 0.6 and error.max() < 0.6, (iou, error)
    assert min(f.confidence for f in result.frames) > 0.5


@real_data
def test_geometric_detector_finds_the_near_real_car_and_tracking_holds_on_a_real_drive() -> None:
    """The KITTI scan with a car 13.5 m ahead: the geometric detector boxes it (BEV IoU ≥
    0.5). On the 40 real raw scans (no labels): the car ahead found in the first is
    tracked through all of them, and each frame an independent detection agrees with the
    tracked box to within half a metre."""
    from services.tracking.detect_geometric import GeometricDetector
    from services.tracking.geometric_tracker import GeometricTracker
    from services.tracking.pipeline import track
    from services.tracking.resets import ResetPolicy
    from services.tracking.run import scan_stream
    from services.tracking.sequence import open_sequence

    points, calibration, labels = _real(3)
    car = kitti.camera_to_lidar(labels.of_type("Car").camera_box, calibration)[0]
    found = GeometricDetector().detect(points)
    assert bev_iou(found.boxes, car[None]).max() >= 0.5
    sequence = open_sequence(REAL_DRIVE)
    first = GeometricDetector().detect(sequence.points(0))
    ahead = first.boxes[np.argmin(np.hypot(first.boxes[:, 0] - 10, first.boxes[:, 1]))]
    result = track(
        scan_stream(sequence, sequence.frames),
        ahead,
        GeometricTracker(),
        None,
        ResetPolicy.parse("never"),
    )
    assert len(result.frames) == 40 and min(f.confidence for f in result.frames) > 0.6
    gaps = []
    for frame, tracked in zip(sequence.frames, result.boxes, strict=True):
        seen = GeometricDetector().detect(sequence.points(frame))
        gaps.append(np.hypot(*(seen.boxes[:, :2] - tracked[:2]).T).min())
    assert np.median(gaps) < 0.5, gaps


def test_association_takes_the_near_car_of_the_targets_size_and_turns_it() -> None:
    from services.tracking.association import associate, reset_box
    from services.tracking.detections import Detections

    tracked = np.array([20.0, 0.0, -0.9, 4.2, 1.8, 1.5, 0.1])
    boxes = np.array(
        [
            [20.6, 0.3, -0.8, 4.0, 1.7, 1.6, 0.1 + np.pi],  # the target, its box turned round
            [19.8, 0.2, -0.8, 10.0, 2.5, 3.0, 0.1],  # a lorry as close: the wrong size
            [24.0, 3.5, -0.8, 4.2, 1.8, 1.5, 0.1],  # a car 5 m away
        ]
    )
    chosen = associate(Detections(boxes, np.array([0.9, 0.9, 0.95]), np.zeros(3, int)), tracked)
    assert chosen.index == 0
    placed = reset_box(boxes[0], tracked)
    np.testing.assert_allclose(placed[[3, 4, 5]], tracked[[3, 4, 5]])  # the target's size
    assert placed[6] == pytest.approx(0.1)  # turned to the tracker's heading
    assert placed[2] - placed[5] / 2 == pytest.approx(-0.8 - 1.6 / 2)  # on its bottom
    # a tracker sure of itself takes no detection 2 m off; an unsure one does
    off = Detections(boxes[:1] + [2.0, 0, 0, 0, 0, 0, 0], np.array([0.9]), np.zeros(1, int))
    assert associate(off, tracked, confidence=1.0).index is None
    assert associate(off, tracked, confidence=0.0).index == 0


def test_a_reset_fuses_by_confidence_and_refuses_a_shape_the_target_does_not_explain() -> None:
    """A sure tracker keeps nearly its own box, a lost one takes nearly the detection's, a
    tracker unsure for a frame or two still trusts its prediction; the given size moves
    little; a detection whose returns the target's shape does not explain is not the
    target."""
    from services.tracking.association import associate, fuse
    from services.tracking.detections import Detections

    tracked = np.array([20.0, 0.0, -0.9, 4.2, 1.8, 1.5, 0.1])
    detection = np.array([21.0, 0.5, -0.8, 4.6, 1.9, 1.6, 0.2 + np.pi])
    sure = fuse(tracked, 1.0, detection, 0.8)
    lost = fuse(tracked, 0.0, detection, 0.8, unsure_frames=10)
    assert abs(sure[0] - 20.0) < 0.2 and abs(lost[0] - 21.0) < 0.1
    assert sure[6] == pytest.approx(0.1, abs=0.02) and lost[6] == pytest.approx(0.2, abs=0.01)
    assert abs(fuse(tracked, 0.0, detection, 0.8, unsure_frames=1)[0] - 20.0) < 0.3
    assert abs(lost[3] - 4.2) < 0.2  # the given length, nudged
    boxes = Detections(detection[None], np.array([0.9]), np.zeros(1, int))
    assert associate(boxes, tracked, lambda box: 0.1, confidence=0.0).index is None
    assert associate(boxes, tracked, lambda box: 0.9, confidence=0.0).index == 0


def test_the_motion_model_learns_where_a_lost_target_went() -> None:
    """Relocated after four frames it could not see the target, the motion model takes the
    way from the last trusted box as the velocity; right after trusted frames a relocation
    is a correction and leaves the velocity alone."""
    from services.tracking.tracker import MotionModel

    model = MotionModel(np.array([10.0, 0, -1, 4, 1.8, 1.5, 0]))
    for _ in range(4):
        predicted = model.advance(None)
        model.update(predicted, learn=False)
    model.relocate(np.array([6.0, 0, -1, 4, 1.8, 1.5, 0]))
    assert model.velocity[:2] == pytest.approx([-1.0, 0.0])
    assert model.advance(None)[0] == pytest.approx(5.0)
    model.update(np.array([5.0, 0, -1, 4, 1.8, 1.5, 0]))
    model.relocate(np.array([5.3, 0, -1, 4, 1.8, 1.5, 0]))
    assert model.velocity[0] == pytest.approx(-1.0)


def test_ego_motion_from_the_scans_matches_the_drives_poses(drive: Path) -> None:
    """Each simulated scan registered to the one before: the motion within a tenth of a
    metre of the simulation's poses as a rule (a street's walls say little about the motion
    along them, and cars driving with the sensor pull it towards standing still), never
    more than 0.35 m, the heading within 0.3°."""
    from services.tracking.egomotion import EgoMotion
    from services.tracking.sequence import open_sequence

    sequence = open_sequence(drive)
    estimate = EgoMotion()
    assert estimate(sequence.points(0)) is None
    errors = []
    for previous, frame in zip(sequence.frames, sequence.frames[1:], strict=False):
        found, truth = estimate(sequence.points(frame)), sequence.ego_motion(previous, frame)
        errors.append(np.linalg.norm(found[:2, 3] - truth[:2, 3]))
        turn = np.arctan2(found[1, 0], found[0, 0]) - np.arctan2(truth[1, 0], truth[0, 0])
        assert abs(np.degrees(turn)) < 0.3
    assert np.median(errors) < 0.1 and max(errors) < 0.35, errors


def test_reset_policies_parse_and_keep_their_budget() -> None:
    from services.tracking.resets import CAPACITY, AdaptiveGate, ResetPolicy
    from services.tracking.tracker import TrackStep

    assert ResetPolicy.parse("every:15") == ResetPolicy("every", period=15)
    assert ResetPolicy.parse("adaptive").budget == pytest.approx(0.10)
    assert ResetPolicy.parse("adaptive:5").text() == "adaptive:5"
    for bad in ("every", "every:0", "adaptive:0", "adaptive:x", "sometimes"):
        with pytest.raises(ValueError, match="never, every:N|every:N needs|adaptive:BUDGET needs"):
            ResetPolicy.parse(bad)
    box = np.array([10, 0, -1, 4, 1.8, 1.5, 0])
    unsure = TrackStep(box, 0.1, 3, box)
    gate = AdaptiveGate(0.1)
    runs = sum(gate.decide(unsure, 0.0) for _ in range(200))
    assert runs <= 0.1 * 200 + CAPACITY
    sure = AdaptiveGate(0.1)
    assert not any(sure.decide(TrackStep(box, 0.95, 200, box), 0.1) for _ in range(100))
    unseen = AdaptiveGate(0.1)  # nothing of the target in view: nothing to correct
    assert not any(unseen.decide(TrackStep(box, 0.0, 0, box), 0.0) for _ in range(20))
    lost = AdaptiveGate(0.1)
    lost.decide(TrackStep(box, 0.95, 200, box), 0.1)
    assert lost.decide(TrackStep(box, 0.95, 20, box), 0.1)  # its returns fell away


def test_bev_cells_hold_the_heights_counts_and_height_over_the_local_floor() -> None:
    from services.tracking.bev import CHANNELS, Window, encode

    window = Window(0.0, 0.0, 32, 32)  # 6.4 m square, 0.2 m cells
    xs, ys = np.meshgrid(np.arange(0.1, 6.4, 0.2), np.arange(0.1, 6.4, 0.2), indexing="ij")
    slope = 0.1 * xs.ravel()  # the ground climbs 10 %
    ground = np.stack([xs.ravel(), ys.ravel(), -1.7 + slope, np.zeros(xs.size)], axis=1)
    pillar = np.array([[3.1, 3.1, z, 0.0] for z in (-1.39, -0.89, -0.19)])  # over x = 3.1
    image = encode(np.concatenate([ground, pillar]), window)
    assert image.shape == (CHANNELS, 32, 32)
    row = col = 15  # the pillar's cell
    assert image[9, row, col] == pytest.approx(np.log1p(4) / np.log(65.0))
    assert image[8, row, col] == pytest.approx((-0.19 + 2.5) / 4.0)
    assert image[:8, row, col].sum() == 3  # the pillar's three slices, its foot the ground's
    # over the local floor: 1.4 m above the lowest return within 2 m (x = 1.1: z -1.59)
    assert image[11, row, col] == pytest.approx((-0.19 + 1.59) / 3.0, abs=1e-6)
    assert image[11, 0, 0] == 0.0 and image[11, 31, 31] == pytest.approx(0.2 / 3.0, abs=1e-6)
    empty = encode(np.zeros((0, 4), np.float32), window)  # a window with nothing in it
    assert not empty[:10].any() and not empty[11].any()


def test_learned_detector_decodes_a_peak_into_its_box() -> None:
    from services.tracking.bev import STRIDE, Window
    from services.tracking.detect_learned import decode

    window = Window.around((0.0, -12.8, 25.6, 12.8))
    output = np.full((9, window.rows // STRIDE, window.cols // STRIDE), -10.0, dtype=np.float32)
    row, col = 14, 20
    output[:, row, col] = [
        4.0,
        0.25,
        0.5,
        -0.9,
        np.log(4.2),
        np.log(1.8),
        np.log(1.5),
        np.sin(0.6),
        np.cos(0.6),
    ]
    found = decode(output, window)
    assert len(found) == 1
    np.testing.assert_allclose(
        found.boxes[0],
        [(row + 0.25) * 0.8, -12.8 + (col + 0.5) * 0.8, -0.9, 4.2, 1.8, 1.5, 0.3],
        atol=1e-5,
    )
    assert found.scores[0] == pytest.approx(1 / (1 + np.exp(-4.0)))


def test_tiny_detector_and_siamese_train_export_and_run(drive: Path, tmp_path: Path) -> None:
    """A detector and a Siamese encoder trained for one short epoch on the small drive: the
    ONNX files carry their metadata and run in the pipeline with resets."""
    from services.lib.nn.onnx_io import read_model
    from services.tracking.detector_training import DetectorTrainConfig, train_detector
    from services.tracking.kinds import TrackParams
    from services.tracking.run import run_tracking
    from services.tracking.siamese import SiameseTrainConfig, candidate_poses, train_siamese

    detector = tmp_path / "detector.onnx"
    meta = train_detector(
        [drive],
        detector,
        DetectorTrainConfig(epochs=1, batch=2, frame_step=3, window_cells=96, threads=2),
    )
    assert (
        meta["architecture"] == "bev-centre"
        and read_model(detector).metadata["parameters"] == meta["parameters"]
    )
    siamese = tmp_path / "siamese.onnx"
    meta = train_siamese(
        [drive], siamese, SiameseTrainConfig(epochs=1, batch=16, samples_per_epoch=32, threads=2)
    )
    assert meta["architecture"] == "sc3d-pointnet" and len(candidate_poses()) == 147
    document = run_tracking(
        drive,
        TrackParams(track_id=0, tracker="siamese", detector="learned", reset="every:4"),
        siamese_model=siamese,
        detector_model=detector,
    )
    assert len(document["frames"]) == 12 and document["detector_runs"] == 2
    assert document["detector_cost_percent"] == pytest.approx(100 * 2 / 12, abs=1e-3)


def test_siamese_candidates_see_the_points_of_their_own_boxes() -> None:
    from services.tracking.siamese import points_in_candidates

    rng = np.random.default_rng(0)
    local = rng.uniform([-3, -2, -0.7], [3, 2, 0.7], size=(4000, 3))
    size = np.array([4.0, 1.8, 1.4])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, np.radians(5)]])
    sets = points_in_candidates(local, size, poses, 64, rng)
    assert sets.shape == (2, 64, 3)
    assert (np.abs(sets) <= size / 2 + 1e-9).all()
    c, s = np.cos(poses[1, 2]), np.sin(poses[1, 2])
    back = sets[1][:, :2] @ np.array([[c, s], [-s, c]]) + poses[1, :2]
    in_original = np.array([np.isclose(local[:, :2], p, atol=1e-6).all(axis=1).any() for p in back])
    assert in_original.all()


# --- commands and jobs --------------------------------------------------------------------


def test_track_commands_run_evaluate_and_refuse(drive: Path, tmp_path: Path) -> None:
    """`vista tracking track` (job tracking.track's command; `run`, its older spelling,
    still works), `vista tracking eval`, and their refusals."""
    runner = CliRunner()
    out = tmp_path / "track.json"
    done = runner.invoke(
        app,
        [
            "tracking",
            "track",
            str(drive),
            "--track-id",
            "0",
            "--reset",
            "every:5",
            "-o",
            str(out),
            "--plot",
            str(tmp_path / "t.png"),
        ],
    )
    assert done.exit_code == 0, done.output
    document = json.loads(out.read_text())
    first = document["frames"][0]
    assert set(first) == {
        "frame",
        "camera_box",
        "lidar_box",
        "confidence",
        "points",
        "detector_ran",
        "reset",
    }
    assert set(first["camera_box"]) == {"h", "w", "l", "x", "y", "z", "ry"}
    assert document["detector_runs"] == 2 and (tmp_path / "t.png").stat().st_size > 10_000
    labels = kitti.read_tracking_labels(drive / "label_02.txt")
    given = labels.camera_box[(labels.track_id == 0) & (labels.frame == 0)][0]
    by_box = tmp_path / "by_box.json"
    done = runner.invoke(  # the older spelling
        app,
        ["tracking", "run", str(drive), "--init-box", " ".join(map(str, given)), "-o", str(by_box)],
    )
    assert done.exit_code == 0 and "deprecated" in done.output, done.output
    evaluated = tmp_path / "eval.json"
    done = runner.invoke(
        app,
        [
            "tracking",
            "eval",
            str(drive),
            str(out),
            str(by_box),
            "-o",
            str(evaluated),
            "--plot",
            str(tmp_path / "ope.png"),
        ],
    )
    assert done.exit_code == 0, done.output
    scores = json.loads(evaluated.read_text())
    assert scores["ope"]["frames"] == 24 and scores["ope"]["success"] > 50
    assert [run["track_id"] for run in scores["runs"]] == [0, 0]
    for arguments, phrase in (
        (["--track-id", "999"], "track 999 is not in"),
        (["--init-box", "1 2 3"], "give seven numbers"),
        (
            ["--track-id", "0", "--init-box", " ".join(map(str, given))],
            "either by track_id (a labelled track)",
        ),
        (["--track-id", "0", "--reset", "every:0"], "every:N (N a whole number from 1)"),
        (["--track-id", "0", "--tracker", "siamese"], "needs its encoder"),
        (["--track-id", "0", "--detector-model", str(tmp_path / "no.onnx")], "no such model file"),
    ):
        refused = runner.invoke(
            app, ["tracking", "track", str(drive), *arguments, "-o", str(tmp_path / "x.json")]
        )
        assert refused.exit_code == 2 and phrase in refused.output, (arguments, refused.output)
    refused = runner.invoke(
        app, ["tracking", "track", str(tmp_path), "--track-id", "0", "-o", str(tmp_path / "x.json")]
    )
    assert refused.exit_code == 2 and "not a LiDAR sequence" in refused.output


def test_train_command_is_the_jobs_and_keeps_its_older_spellings(
    drive: Path, tmp_path: Path
) -> None:
    """`vista tracking train` takes job tracking.train's params (the network among them);
    `vista tracking train siamese|detector|default-detector …` still work for this release,
    saying they are deprecated; a knob out of its network's range is refused by the model."""
    from services.lib.nn.onnx_io import read_model

    runner = CliRunner()
    tiny = ["--epochs", "1", "--batch", "16", "--samples", "32", "--threads", "2"]
    for spelling in (
        ["train", str(drive), "--network", "siamese"],
        ["train", "siamese", str(drive)],
    ):
        out = tmp_path / f"{len(spelling)}.onnx"
        done = runner.invoke(app, ["tracking", *spelling, *tiny, "-o", str(out)])
        assert done.exit_code == 0 and "validation similarity MSE" in done.output, done.output
        assert read_model(out).metadata["architecture"] == "sc3d-pointnet"
        assert ("deprecated" in done.output) == ("siamese" in spelling[:2])
    out = str(tmp_path / "x.onnx")
    for arguments, phrase in (
        (["train", "detector", str(drive), "--from", "nowhere.onnx"], "no such model file"),
        (["train", str(drive), "--window", "100"], "--window: 100 is not a multiple of 16"),
        (["train", str(drive), "--network", "siamese", "--batch", "1"], "at least 2 pairs"),
        (["train", str(drive), "--batch", "512"], "at most 256 windows"),
        (["train", str(drive), "--network", "siamese", "--fine-tune"], "applies to the detector"),
    ):
        refused = runner.invoke(app, ["tracking", *arguments, "-o", out])
        assert refused.exit_code == 2 and phrase in refused.output, (arguments, refused.output)
    shown = runner.invoke(app, ["tracking", "train", "default-detector", "--help"])
    assert shown.exit_code == 0 and "vista tracking build-default" in shown.output


@real_data
def test_detect_command_writes_kittis_results_and_scores_them(tmp_path: Path) -> None:
    out = tmp_path / "results"
    done = CliRunner().invoke(
        app,
        [
            "tracking",
            "detect",
            str(REAL_OBJECTS / "velodyne"),
            "--calib",
            str(REAL_OBJECTS / "calib"),
            "-o",
            str(out),
            "--labels",
            str(REAL_OBJECTS / "label_2"),
        ],
    )
    assert done.exit_code == 0, done.output
    assert "recall within 40 m" in done.output
    results = kitti.read_object_labels(out / "000003.txt")
    assert set(results.type) == {"Car"} and np.isfinite(results.score).all()
    calibration = kitti.read_calibration(REAL_OBJECTS / "calib" / "000003.txt")
    truth = kitti.camera_to_lidar(
        kitti.read_object_labels(REAL_OBJECTS / "label_2" / "000003.txt").of_type("Car").camera_box,
        calibration,
    )
    assert bev_iou(kitti.camera_to_lidar(results.camera_box, calibration), truth).max() >= 0.5


def test_lidar_archives_unpack_and_refuse_the_unsafe(drive: Path, tmp_path: Path) -> None:
    import tarfile

    from services.lib.archive import ArchiveError
    from services.tracking.lidar_archive import extract_lidar, inspect_lidar
    from tests.lidarfiles import pack_sequence

    packed = pack_sequence(drive, tmp_path / "drive.tar.gz")
    found = inspect_lidar(packed)
    assert (found.frames, found.poses, found.media_type) == (12, True, "application/gzip")
    assert found.tracks == len(
        np.unique(kitti.read_tracking_labels(drive / "label_02.txt").track_id)
    )
    out = extract_lidar(packed, tmp_path / "out")
    assert (
        out.frames == 12
        and (tmp_path / "out" / "velodyne" / "000011.bin").read_bytes()
        == (drive / "velodyne" / "000011.bin").read_bytes()
    )
    unsafe = tmp_path / "unsafe.tar"
    with tarfile.open(unsafe, "w") as archive:
        archive.add(drive / "velodyne" / "000000.bin", arcname="s/velodyne/000000.bin")
        archive.add(drive / "velodyne" / "000001.bin", arcname="s/velodyne/../../evil.bin")
        archive.add(drive / "calib.txt", arcname="s/calib.txt")
    extract_lidar(unsafe, tmp_path / "safe")
    written = sorted(
        str(p.relative_to(tmp_path / "safe")) for p in (tmp_path / "safe").rglob("*") if p.is_file()
    )
    assert written == ["calib.txt", "velodyne/000000.bin"] and not list(tmp_path.rglob("evil.bin"))
    misnamed = tmp_path / "misnamed.tar"
    with tarfile.open(misnamed, "w") as archive:
        archive.add(drive / "velodyne" / "000000.bin", arcname="s/velodyne/scan one.bin")
        archive.add(drive / "calib.txt", arcname="s/calib.txt")
    with pytest.raises(ArchiveError, match="named by its frame number"):
        inspect_lidar(misnamed)
    nocalib = tmp_path / "nocalib.tar"
    with tarfile.open(nocalib, "w") as archive:
        archive.add(drive / "velodyne" / "000000.bin", arcname="s/velodyne/000000.bin")
    with pytest.raises(ArchiveError, match="no calib.txt"):
        inspect_lidar(nocalib)


def test_the_bench_sweep_scores_each_policy(drive: Path) -> None:
    """The bench's reset sweep on the small drive: one row per policy with its cost — every
    frame after the first for every:1, none for never — and OPE scores."""
    from services.tracking.bench import simulated_workload, sweep
    from services.tracking.detect_geometric import GeometricDetector
    from services.tracking.geometric_tracker import GeometricTracker

    work = simulated_workload([drive], min_frames=10)
    assert work.tracklets and all(len(t.frames) >= 10 for _, t in work.tracklets)
    rows = sweep(work, GeometricTracker, GeometricDetector(), ("every:1", "never"))
    frames = sum(len(t.frames) for _, t in work.tracklets)
    assert [r["reset"] for r in rows] == ["every:1", "never"]
    assert rows[0]["cost_percent"] == pytest.approx(
        100 * (frames - len(work.tracklets)) / frames, abs=0.01
    )
    assert rows[1]["cost_percent"] == 0 and 0 < rows[1]["success"] <= 100
    # The tracker alone leaves out the detector's time: faster where the detector runs,
    # the same where it never does.
    assert rows[0]["tracker_fps"] > rows[0]["compute_fps"] > 0
    assert rows[1]["tracker_fps"] == pytest.approx(rows[1]["compute_fps"], rel=0.01)


def test_detection_labels_do_not_overlap() -> None:
    """Three boxes side by side and a fourth inside the first: every score label gets a
    place of its own, inside the image."""
    from services.tracking.detect import label_places

    boxes = [(100, 50, 200, 150), (110, 52, 210, 150), (120, 54, 220, 150), (105, 60, 180, 140)]
    sizes = [(40, 16)] * 4
    places = label_places(boxes, sizes, (640, 200))
    rects = [(x, y, x + w, y + h) for (x, y), (w, h) in zip(places, sizes, strict=True)]
    for i, a in enumerate(rects):
        assert a[0] >= 0 and a[2] <= 640 and a[1] >= 0 and a[3] <= 200
        for b in rects[i + 1 :]:
            assert a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1], (a, b)
