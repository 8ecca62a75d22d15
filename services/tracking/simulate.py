"""Simulated LiDAR drives with ground truth, in KITTI tracking's formats.

``simulate_sequence`` writes a sequence folder as ``vista tracking track`` reads it:
``velodyne/NNNNNN.bin`` (one HDL-64E turn a frame, 10 Hz), ``calib.txt`` (the tracking
benchmark's, KITTI's 2011-09-26 rig), ``label_02.txt`` (every car, van, pedestrian and
cyclist the camera sees within 80 m: track id, 2D box, truncation, occlusion from the
LiDAR's view, 3D box, heading) and ``poses.txt`` (the camera's poses, odometry format);
``simulation.json`` adds what KITTI has no field for (each track's shape, whether it
moves).

A label's box is where its object was when the turning beams passed it, in the sensor's
frame of that instant — where its points are.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from services.lib import kitti
from services.lib.boxes import YAW, H, L, W, corners, to_box_frame, wrap
from services.tracking import lidar
from services.tracking.scene import Agent, Road, Street, placements, random_street

FPS = 10.0
IMAGE_SIZE = (1242, 375)
LABEL_RANGE_M = 80.0
MOVING_RANGE_M = 120.0
# KITTI's published 2011-09-26 calibration (the rig of the raw drives and the tracking set)
KITTI_P2 = np.array(
    [
        [721.5377, 0.0, 609.5593, 44.85728],
        [0.0, 721.5377, 172.854, 0.2163791],
        [0.0, 0.0, 1.0, 0.002745884],
    ]
)
KITTI_R_RECT = np.array(
    [
        [0.9999239, 0.00983776, -0.007445048],
        [-0.009869795, 0.9999421, -0.004278459],
        [0.007402527, 0.004351614, 0.9999631],
    ]
)
KITTI_VELO_TO_CAM = np.array(
    [
        [0.007533745, -0.9999714, -0.000616602, -0.004069766],
        [0.01480249, 0.0007280733, -0.9998902, -0.07631618],
        [0.9998621, 0.00752379, 0.01480755, -0.2717806],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def kitti_calibration() -> kitti.Calibration:
    return kitti.Calibration(P2=KITTI_P2, R0_rect=KITTI_R_RECT, Tr_velo_to_cam=KITTI_VELO_TO_CAM)


@dataclass(frozen=True)
class SimulationSummary:
    frames: int
    points_per_scan: float
    labels: int
    tracks: int
    seconds: float


def sensor_poses(street: Street, frames: np.ndarray) -> np.ndarray:
    """(K, 4, 4) world_T_sensor at (fractional) frames: on the ego car's lane, 1.73 m up,
    facing along the road and tilted with its slope."""
    index = np.arange(len(street.ego_s))
    s = np.interp(frames, index, street.ego_s)
    xy, z, heading = street.road.pose(s, np.full_like(s, street.ego_d))
    return placements(xy, z, heading, street.road.pitch(s), lidar.MOUNT_HEIGHT_M)


def _object_boxes(street: Street, frame: int, visible: np.ndarray) -> np.ndarray:
    """(A, 7) each agent's box in the sensor frame when the beams passed it (nan: too far)."""
    road = street.road
    sensor_now = sensor_poses(street, np.array([float(frame)]))[0]
    sensor_from_world = np.linalg.inv(sensor_now)
    boxes = np.full((len(street.agents), 7), np.nan)
    for index in np.flatnonzero(visible):
        agent = street.agents[index]
        size = agent.mesh.box_size
        centre = agent.pose(road, frame) @ np.array([0, 0, size[2] / 2, 1])
        azimuth = np.arctan2(*(sensor_from_world @ centre)[[1, 0]])
        at = frame - azimuth / (2 * np.pi)  # the beams pass azimuth a at −a/2π of a turn
        sensor_T_world = np.linalg.inv(sensor_poses(street, np.array([at]))[0])
        pose = sensor_T_world @ agent.pose(road, at)
        boxes[index, :3] = (pose @ np.array([0, 0, size[2] / 2, 1]))[:3]
        boxes[index, L], boxes[index, W], boxes[index, H] = size
        boxes[index, YAW] = wrap(np.arctan2(pose[1, 0], pose[0, 0]))
    return boxes


def _occlusion(model: lidar.LidarModel, box: np.ndarray, hits: int) -> int:
    """KITTI's occlusion level from the share of the beams aimed at the box that reached it:
    0 fully visible, 1 partly, 2 largely occluded, 3 unknown (no beam aimed at it)."""
    directions, _ = model.directions()
    azimuths = np.arctan2(*corners(box)[:, [1, 0]].T)
    centre = np.arctan2(box[1], box[0])
    spread = wrap(azimuths - centre)
    column = lambda azimuth: (np.pi - azimuth) / (2 * np.pi) * model.columns - 0.5  # noqa: E731
    first, last = sorted((column(centre + spread.max()), column(centre + spread.min())))
    columns = np.arange(int(np.floor(first)) - 1, int(np.ceil(last)) + 2) % model.columns
    rays = (np.arange(len(model.elevations_deg))[:, None] * model.columns + columns).ravel()
    local = to_box_frame(directions[rays], np.array([0, 0, 0, 1, 1, 1, box[YAW]]))
    origin = to_box_frame(np.zeros((1, 3)), box)[0]
    half = box[L:YAW] / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - origin) / local
        t2 = (half - origin) / local
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    aimed = int(((far >= near) & (far > 0) & (near < model.max_range_m)).sum())
    if aimed == 0:
        return 3
    share = hits / (0.7 * aimed)
    return 0 if share >= 0.5 else 1 if share >= 0.15 else 2


def _frame_labels(
    street: Street,
    frame: int,
    calibration: kitti.Calibration,
    scan: lidar.Scan,
    model: lidar.LidarModel,
) -> list[tuple]:
    """(track id, type, truncation, occlusion, alpha, 2D box, camera box) of each agent the
    camera sees within ``LABEL_RANGE_M``."""
    sensor = sensor_poses(street, np.array([float(frame)]))[0]
    near = []
    for agent in street.agents:
        position = agent.pose(street.road, frame)[:3, 3]
        near.append(np.linalg.norm(position[:2] - sensor[:2, 3]) < LABEL_RANGE_M + 10)
    boxes = _object_boxes(street, frame, np.array(near))
    rows = []
    candidates = np.flatnonzero(np.isfinite(boxes[:, 0]))
    if not len(candidates):
        return rows
    camera = kitti.lidar_to_camera(boxes[candidates], calibration)
    image, truncated = kitti.image_boxes(boxes[candidates], calibration, IMAGE_SIZE)
    alpha = kitti.observation_angle(camera)
    hits = np.bincount(scan.hit_object[scan.hit_object >= 0], minlength=len(street.agents))
    for row, index in enumerate(candidates):
        distance = np.linalg.norm(boxes[index, :2])
        if camera[row, 5] < 1.0 or truncated[row] >= 0.99 or distance > LABEL_RANGE_M:
            continue
        occluded = _occlusion(model, boxes[index], int(hits[index]))
        rows.append(
            (
                index,
                street.agents[index].type,
                truncated[row],
                occluded,
                alpha[row],
                image[row],
                camera[row],
            )
        )
    return rows


def _labels(rows: list[tuple]) -> kitti.Labels:
    """Rows of (frame, track, type, truncation, occlusion, alpha, 2D box, camera box)."""
    if not rows:
        return kitti.empty_labels()
    columns = list(zip(*rows, strict=True))
    return kitti.Labels(
        frame=np.array(columns[0], dtype=int),
        track_id=np.array(columns[1], dtype=int),
        type=tuple(columns[2]),
        truncated=np.array(columns[3], dtype=float),
        occluded=np.array(columns[4], dtype=int),
        alpha=np.array(columns[5], dtype=float),
        bbox=np.array(columns[6], dtype=float).reshape(-1, 4),
        camera_box=np.array(columns[7], dtype=float).reshape(-1, 7),
        score=np.full(len(rows), np.nan),
    )


def _agent_poses(agent: Agent, road: Road, frame: int, offsets_s: np.ndarray) -> np.ndarray:
    return agent.poses(road, frame + offsets_s * FPS)


def _sensor_poses_at(street: Street, frame: int, offsets_s: np.ndarray) -> np.ndarray:
    return sensor_poses(street, frame + offsets_s * FPS)


def simulate_sequence(
    out_dir: Path,
    *,
    frames: int = 300,
    cars: int = 8,
    seed: int = 0,
    model: lidar.LidarModel | None = None,
    threads: int = 2,
    progress: Callable[[int], None] | None = None,
) -> SimulationSummary:
    """Simulate a drive of ``frames`` frames with ``cars`` moving cars (the first is led by
    the ego car's lane ahead of it for the whole drive) and write it to ``out_dir``."""
    import time

    if frames < 1:
        raise ValueError("frames must be at least 1")
    started = time.perf_counter()
    model = model or lidar.LidarModel()
    rng = np.random.default_rng(seed)
    street = random_street(frames, cars, rng, FPS)
    road = street.road
    standing = [i for i, moving in enumerate(street.moving) if not moving]
    world = lidar.StaticWorld(
        street.static_meshes
        + [street.agents[i].mesh.placed(street.agents[i].pose(road, 0)) for i in standing],
        [-1] * len(street.static_meshes) + standing,
    )
    calibration = kitti_calibration()
    out_dir = Path(out_dir)
    (out_dir / "velodyne").mkdir(parents=True, exist_ok=True)
    movers = {i: lidar.Mover(i, street.agents[i].mesh) for i in np.flatnonzero(street.moving)}
    label_rows, point_counts = [], []
    for frame in range(frames):
        sensor = sensor_poses(street, np.array([float(frame)]))[0]
        near = [
            (mover, partial(_agent_poses, street.agents[i], road, frame))
            for i, mover in movers.items()
            if np.linalg.norm(street.agents[i].pose(road, frame)[:2, 3] - sensor[:2, 3])
            < MOVING_RANGE_M
        ]
        scan = lidar.scan(
            model,
            world,
            partial(_sensor_poses_at, street, frame),
            near,
            rng,
            threads=threads,
        )
        kitti.write_velodyne(out_dir / "velodyne" / f"{frame:06d}.bin", scan.points)
        point_counts.append(len(scan.points))
        label_rows += [
            (frame, *row) for row in _frame_labels(street, frame, calibration, scan, model)
        ]
        if progress:
            progress(frame)
    kitti.write_calibration(out_dir / "calib.txt", calibration)
    labels = _labels(label_rows)
    (out_dir / "label_02.txt").write_text(kitti.format_labels(labels, tracking=True, decimals=6))
    velo_poses = sensor_poses(street, np.arange(frames, dtype=float))
    velo0_T_velo = np.linalg.inv(velo_poses[0]) @ velo_poses
    rect_T_velo = calibration.rect_T_velo
    kitti.write_poses(
        out_dir / "poses.txt", rect_T_velo @ velo0_T_velo @ np.linalg.inv(rect_T_velo)
    )
    tracks = sorted({int(t) for t in labels.track_id})
    document = {
        "seed": seed,
        "frames": frames,
        "cars": cars,
        "fps": FPS,
        "lidar": {
            "rings": len(model.elevations_deg),
            "columns": model.columns,
            "mount_height_m": lidar.MOUNT_HEIGHT_M,
        },
        "road": street.notes,
        "tracks": {
            str(i): {
                "type": street.agents[i].type,
                "shape": street.agents[i].shape,
                "moving": bool(street.moving[i]),
            }
            for i in tracks
        },
        "followed_track": 0,
    }
    (out_dir / "simulation.json").write_text(json.dumps(document, indent=1) + "\n")
    return SimulationSummary(
        frames=frames,
        points_per_scan=float(np.mean(point_counts)),
        labels=len(labels),
        tracks=len(tracks),
        seconds=time.perf_counter() - started,
    )
