"""KITTI's file formats, so users run vista on their own downloads as they are (the one
module that reads and writes them; the depth service's drive layout is ``depth/drive.py``).

- Depth PNG (the depth benchmark's convention): uint16, metres × 256, 0 = no measurement.

- ``velodyne/NNNNNN.bin``: float32 little-endian ``x y z reflectance`` per point, metres,
  the Velodyne's frame (x forward, y left, z up).
- Calibration: the object benchmark's ``calib/NNNNNN.txt`` (``P2:``, ``R0_rect:``,
  ``Tr_velo_to_cam:``), the tracking benchmark's ``calib/NNNN.txt`` (``P2:``, ``R_rect``,
  ``Tr_velo_cam``, ``Tr_imu_velo``), a raw drive's ``calib_velo_to_cam.txt`` +
  ``calib_cam_to_cam.txt`` or vista's shared ``calib.json`` (``P_rect_02``, ``R_rect_00``,
  ``cam0_T_velo``). A LiDAR point X maps into the rectified camera frame by
  ``rect_T_velo = R0_rect · Tr_velo_to_cam`` and to pixels by ``P2``.
- Labels: ``label_2`` (object: ``type truncated occluded alpha x1 y1 x2 y2 h w l x y z
  rotation_y [score]``) and ``label_02`` (tracking: ``frame track_id`` before the same
  fields). Boxes are metres, ``x y z`` the bottom centre in the rectified camera frame
  (y down), ``rotation_y`` about the camera's y axis.
- ``poses.txt`` (the odometry benchmark's): per frame the 3 × 4 row-major pose of the
  rectified camera 0 in the first frame's: ``cam0_T_cami``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from services.lib.boxes import YAW, H, L, W, corners, wrap

POINT_BYTES = 16
DONT_CARE = "DontCare"


class KittiError(ValueError):
    """A KITTI file that cannot be read as its format says (the sentence says where)."""


def read_velodyne(path: Path) -> np.ndarray:
    """(N, 4) float32 ``x y z reflectance`` (metres) from a KITTI ``.bin`` scan."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise KittiError(f"{path}: cannot read the scan ({exc.strerror or exc})") from None
    if size % POINT_BYTES:
        raise KittiError(
            f"{path}: {size:,} bytes is not a whole number of points (16 bytes each: float32 "
            "x y z reflectance)"
        )
    points = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    finite = np.isfinite(points).all(axis=1)
    return points if finite.all() else points[finite]


def write_velodyne(path: Path, points: np.ndarray) -> None:
    """(N, 4) ``x y z reflectance`` (metres) as a KITTI ``.bin`` scan."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 4:
        raise ValueError(f"a scan is (N, 4) x y z reflectance, got {points.shape}")
    path.parent.mkdir(parents=True, exist_ok=True)
    np.ascontiguousarray(points, dtype="<f4").tofile(path)


def _homogeneous(matrix: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[: matrix.shape[0], : matrix.shape[1]] = matrix
    return out


@dataclass(frozen=True)
class Calibration:
    P2: np.ndarray
    """(3, 4) projection of the rectified camera frame into image 2 (pixels)."""
    R0_rect: np.ndarray
    """(3, 3) rectifying rotation of camera 0."""
    Tr_velo_to_cam: np.ndarray
    """(4, 4) the Velodyne's frame into camera 0's (unrectified)."""
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    """Other matrices the file had (P0, P1, P3, Tr_imu_velo …), written back as read."""

    @property
    def rect_T_velo(self) -> np.ndarray:
        return _homogeneous(self.R0_rect) @ self.Tr_velo_to_cam

    @property
    def velo_T_rect(self) -> np.ndarray:
        return np.linalg.inv(self.rect_T_velo)

    def velo_to_image(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) of LiDAR points (N, ≥3) in image 2 and their depth (N,) in metres
        along the camera's axis (≤ 0: behind the camera)."""
        rect = points[:, :3] @ self.rect_T_velo[:3, :3].T + self.rect_T_velo[:3, 3]
        projected = rect @ self.P2[:, :3].T + self.P2[:, 3]
        depth = projected[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            pixels = projected[:, :2] / depth[:, None]
        return pixels, depth


def _read_text(path: Path, what: str) -> str:
    try:
        return Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise KittiError(f"{path}: cannot read the {what} ({exc})") from None


def key_values(text: str, path: Path | str) -> dict[str, np.ndarray]:
    """A calibration file's ``key: numbers`` lines (``calib_time`` and blank lines skipped)."""
    values = {}
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        key, _, rest = line.replace(":", " ", 1).partition(" ")
        try:
            values[key.strip()] = np.array(rest.split(), dtype=np.float64)
        except ValueError:
            if key.strip() in ("calib_time",):
                continue
            raise KittiError(f"{path}, line {number}: {key!r} is not a list of numbers") from None
    return values


def _shaped(
    values: dict[str, np.ndarray], path: Path | str, key: str, shape: tuple[int, int]
) -> np.ndarray:
    found = values[key]
    if found.size != shape[0] * shape[1]:
        raise KittiError(
            f"{path}: {key} has {found.size} numbers, {shape[0]} × {shape[1]} expected"
        )
    if not np.isfinite(found).all():
        raise KittiError(f"{path}: {key} holds non-finite numbers")
    return found.reshape(shape)


ALIASES = {
    "R0_rect": ("R0_rect", "R_rect", "R_rect_00"),
    "Tr_velo_to_cam": ("Tr_velo_to_cam", "Tr_velo_cam"),
    "P2": ("P2", "P_rect_02"),
}


def _pick(values: dict[str, np.ndarray], name: str) -> str | None:
    return next((key for key in ALIASES[name] if key in values), None)


def read_calibration(path: Path) -> Calibration:
    """A calibration from an object or tracking ``calib`` file, a raw drive's
    ``calib_cam_to_cam.txt`` (its ``calib_velo_to_cam.txt`` beside it) or ``calib.json``."""
    path = Path(path)
    if path.suffix == ".json":
        return _read_calibration_json(path)
    values = key_values(_read_text(path, "calibration"), path)
    if path.name == "calib_cam_to_cam.txt":
        velo = path.with_name("calib_velo_to_cam.txt")
        if not velo.exists():
            raise KittiError(f"{path}: a raw drive's calibration needs {velo.name} beside it")
        rigid = key_values(_read_text(velo, "calibration"), velo)
        values["Tr_velo_to_cam"] = np.column_stack(
            [_shaped(rigid, velo, "R", (3, 3)), _shaped(rigid, velo, "T", (3, 1))]
        ).ravel()
    return _calibration(values, path)


def parse_calibration(text: str, name: str) -> Calibration:
    """An object or tracking calib file's text (``name`` for the errors)."""
    return _calibration(key_values(text, name), name)


def _calibration(values: dict[str, np.ndarray], path: Path | str) -> Calibration:
    keys = {name: _pick(values, name) for name in ALIASES}
    missing = [ALIASES[name][0] for name, key in keys.items() if key is None]
    if missing:
        raise KittiError(
            f"{path}: no {', '.join(missing)} (a KITTI object or tracking calib file has P2, "
            "R0_rect or R_rect, Tr_velo_to_cam or Tr_velo_cam)"
        )
    used = set(keys.values())
    return Calibration(
        P2=_shaped(values, path, keys["P2"], (3, 4)),
        R0_rect=_shaped(values, path, keys["R0_rect"], (3, 3)),
        Tr_velo_to_cam=_homogeneous(_shaped(values, path, keys["Tr_velo_to_cam"], (3, 4))),
        extra={k: v for k, v in values.items() if k not in used and k[:1] in ("P", "T")},
    )


def _read_calibration_json(path: Path) -> Calibration:
    try:
        text = path.read_text()
    except OSError as exc:
        raise KittiError(f"{path}: {exc}") from None
    return parse_calibration_json(text, path)


def parse_calibration_json(text: str, name: Path | str) -> Calibration:
    """vista's shared ``calib.json`` (``P_rect_02``, ``R_rect_00``, ``cam0_T_velo``);
    ``name`` for the errors."""
    try:
        document = json.loads(text)
        P2 = np.array(document["P_rect_02"], dtype=np.float64).reshape(3, 4)
        R0 = np.array(document["R_rect_00"], dtype=np.float64).reshape(3, 3)
        velo = np.array(document["cam0_T_velo"], dtype=np.float64).reshape(4, 4)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise KittiError(
            f"{name}: not a calibration JSON with P_rect_02, R_rect_00 and cam0_T_velo ({exc})"
        ) from None
    return Calibration(P2=P2, R0_rect=R0, Tr_velo_to_cam=velo)


def write_calibration(path: Path, calibration: Calibration) -> None:
    """The tracking benchmark's calib file (``P0:``…``P3:``, ``R_rect``, ``Tr_velo_cam``,
    ``Tr_imu_velo`` as known)."""

    def line(key: str, matrix: np.ndarray, colon: bool) -> str:
        return f"{key}{':' if colon else ''} " + " ".join(f"{v:.12e}" for v in np.ravel(matrix))

    rows = []
    for name in ("P0", "P1", "P2", "P3"):
        matrix = calibration.P2 if name == "P2" else calibration.extra.get(name)
        if matrix is not None:
            rows.append(line(name, matrix, True))
    rows.append(line("R_rect", calibration.R0_rect, False))
    rows.append(line("Tr_velo_cam", calibration.Tr_velo_to_cam[:3], False))
    if "Tr_imu_velo" in calibration.extra:
        rows.append(line("Tr_imu_velo", calibration.extra["Tr_imu_velo"], False))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(rows) + "\n")


@dataclass(frozen=True)
class Labels:
    """Rows of a ``label_2`` or ``label_02`` file (object files have frame 0, track −1)."""

    frame: np.ndarray
    track_id: np.ndarray
    type: tuple[str, ...]
    truncated: np.ndarray
    occluded: np.ndarray
    alpha: np.ndarray
    bbox: np.ndarray
    """(N, 4) the 2D box in image 2, pixels: left, top, right, bottom."""
    camera_box: np.ndarray
    """(N, 7) ``h w l x y z rotation_y`` (metres, radians; rectified camera frame)."""
    score: np.ndarray
    """(N,) the 16th field when given (detections), else nan."""

    def __len__(self) -> int:
        return len(self.frame)

    def select(self, mask: np.ndarray) -> Labels:
        mask = np.asarray(mask)
        return Labels(
            self.frame[mask],
            self.track_id[mask],
            tuple(np.asarray(self.type, dtype=object)[mask]) if len(self.type) else (),
            self.truncated[mask],
            self.occluded[mask],
            self.alpha[mask],
            self.bbox[mask],
            self.camera_box[mask],
            self.score[mask],
        )

    def of_type(self, *types: str) -> Labels:
        return self.select(np.isin(np.asarray(self.type, dtype=object), types))

    def with_frame(self, frame: int) -> Labels:
        """The rows, all in ``frame``."""
        return replace(self, frame=np.full(len(self), frame, dtype=int))

    def with_track_ids(self, track_id: np.ndarray) -> Labels:
        return replace(self, track_id=np.asarray(track_id, dtype=int))


def concatenate_labels(parts: list[Labels]) -> Labels:
    """The rows of ``parts`` in order, as one ``Labels``."""
    if not parts:
        return empty_labels()
    return Labels(
        *(
            tuple(t for part in parts for t in part.type)
            if name == "type"
            else np.concatenate([getattr(part, name) for part in parts])
            for name in Labels.__dataclass_fields__
        )
    )


def empty_labels() -> Labels:
    return Labels(
        np.zeros(0, int), np.zeros(0, int), (), np.zeros(0), np.zeros(0, int), np.zeros(0),
        np.zeros((0, 4)), np.zeros((0, 7)), np.zeros(0),
    )  # fmt: skip


def parse_labels(text: str, path: Path | str, *, tracking: bool) -> Labels:
    """Label lines (``label_02`` with ``tracking``, else ``label_2``); ``path`` names them
    in the errors."""
    lines = [line.split() for line in text.splitlines() if line.strip()]
    lead = 2 if tracking else 0
    expected = "frame track_id type …" if tracking else "type truncated …"
    rows = []
    for number, fields in enumerate(lines, 1):
        if len(fields) not in (lead + 15, lead + 16):
            raise KittiError(
                f"{path}, line {number}: {len(fields)} fields; a KITTI "
                f"{'label_02' if tracking else 'label_2'} line has {lead + 15} ({expected}), "
                f"or {lead + 16} with a score"
            )
        try:
            numbers = [float(v) for v in fields[:lead] + fields[lead + 1 :]]
        except ValueError:
            raise KittiError(
                f"{path}, line {number}: a field that should be a number is not"
            ) from None
        rows.append((fields[lead], numbers))
    if not rows:
        return empty_labels()
    numbers = np.array([r[1] + [np.nan] * (lead + 15 - len(r[1])) for r in rows])
    if tracking:
        frame, track, rest = numbers[:, 0].astype(int), numbers[:, 1].astype(int), numbers[:, 2:]
    else:
        frame, track, rest = np.zeros(len(rows), int), np.full(len(rows), -1), numbers
    return Labels(
        frame=frame,
        track_id=track,
        type=tuple(r[0] for r in rows),
        truncated=rest[:, 0],
        occluded=rest[:, 1].astype(int),
        alpha=rest[:, 2],
        bbox=rest[:, 3:7],
        camera_box=rest[:, 7:14],
        score=rest[:, 14],
    )


def read_object_labels(path: Path) -> Labels:
    """A ``label_2`` file (the object benchmark's: one scan)."""
    return parse_labels(_read_text(path, "labels"), path, tracking=False)


def read_tracking_labels(path: Path) -> Labels:
    """A ``label_02`` file (the tracking benchmark's: every frame of a sequence)."""
    return parse_labels(_read_text(path, "labels"), path, tracking=True)


def format_labels(labels: Labels, *, tracking: bool, decimals: int = 2) -> str:
    """KITTI label lines (``label_02`` with ``tracking``), a score field where it is finite;
    KITTI's own files give ``decimals`` = 2."""
    lines = []
    for i in range(len(labels)):
        number = f"{{:.{decimals}f}}".format
        fields = [f"{labels.frame[i]} {labels.track_id[i]}"] if tracking else []
        fields += [
            labels.type[i],
            f"{labels.truncated[i]:.2f} {labels.occluded[i]:d} {number(labels.alpha[i])}",
            " ".join(number(v) for v in labels.bbox[i]),
            " ".join(number(v) for v in labels.camera_box[i]),
        ]
        if np.isfinite(labels.score[i]):
            fields.append(f"{labels.score[i]:.4f}")
        lines.append(" ".join(fields))
    return "".join(line + "\n" for line in lines)


def camera_to_lidar(camera_boxes: np.ndarray, calibration: Calibration) -> np.ndarray:
    """(N, 7) KITTI ``h w l x y z ry`` (rectified camera frame) → LiDAR boxes ``x y z l w h
    yaw`` (centre): the bottom centre raised by half the height, the heading turned through
    the calibration's rotation."""
    cam = np.asarray(camera_boxes, dtype=np.float64).reshape(-1, 7)
    velo_T_rect = calibration.velo_T_rect
    height, ry = cam[:, 0], cam[:, 6]
    lift = np.column_stack([np.zeros_like(height), height / 2, np.zeros_like(height)])
    centre_rect = cam[:, 3:6] - lift
    centre = centre_rect @ velo_T_rect[:3, :3].T + velo_T_rect[:3, 3]
    heading_rect = np.column_stack([np.cos(ry), np.zeros_like(ry), -np.sin(ry)])
    heading = heading_rect @ velo_T_rect[:3, :3].T
    boxes = np.empty((len(cam), 7))
    boxes[:, :3] = centre
    boxes[:, L], boxes[:, W], boxes[:, H] = cam[:, 2], cam[:, 1], height
    boxes[:, YAW] = np.arctan2(heading[:, 1], heading[:, 0])
    return boxes


def lidar_to_camera(boxes: np.ndarray, calibration: Calibration) -> np.ndarray:
    """The inverse of ``camera_to_lidar``: LiDAR boxes → KITTI ``h w l x y z ry``."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
    rect_T_velo = calibration.rect_T_velo
    centre = boxes[:, :3] @ rect_T_velo[:3, :3].T + rect_T_velo[:3, 3]
    heading = np.column_stack([np.cos(boxes[:, YAW]), np.sin(boxes[:, YAW]), np.zeros(len(boxes))])
    heading_rect = heading @ rect_T_velo[:3, :3].T
    cam = np.empty((len(boxes), 7))
    cam[:, 0], cam[:, 1], cam[:, 2] = boxes[:, H], boxes[:, W], boxes[:, L]
    cam[:, 3:6] = centre + np.column_stack(
        [np.zeros(len(boxes)), boxes[:, H] / 2, np.zeros(len(boxes))]
    )
    cam[:, 6] = wrap(np.arctan2(-heading_rect[:, 2], heading_rect[:, 0]))
    return cam


def observation_angle(camera_boxes: np.ndarray) -> np.ndarray:
    """KITTI's ``alpha``: the heading as seen from the camera (ry − atan2(x, z)), in (−π, π]."""
    cam = np.asarray(camera_boxes, dtype=np.float64).reshape(-1, 7)
    return wrap(cam[:, 6] - np.arctan2(cam[:, 3], cam[:, 5]))


def _area(rectangles: np.ndarray) -> np.ndarray:
    return np.maximum(rectangles[:, 2] - rectangles[:, 0], 0) * np.maximum(
        rectangles[:, 3] - rectangles[:, 1], 0
    )


def image_boxes(
    boxes: np.ndarray, calibration: Calibration, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4) 2D boxes (left, top, right, bottom; clipped to the ``size`` = (width, height)
    image) of LiDAR boxes' corners in image 2, and (N,) the share of each box outside the
    image (KITTI's truncation, 0–1; 1 when no corner is in front of the camera)."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
    if not len(boxes):
        return np.zeros((0, 4)), np.zeros(0)
    pixels, depth = calibration.velo_to_image(corners(boxes).reshape(-1, 3))
    pixels, depth = pixels.reshape(-1, 8, 2), depth.reshape(-1, 8)
    ahead = depth > 0.1
    low = np.where(ahead[..., None], pixels, np.inf).min(axis=1)
    high = np.where(ahead[..., None], pixels, -np.inf).max(axis=1)
    full = np.concatenate([low, high], axis=1)
    width, height = size
    clipped = np.column_stack(
        [np.clip(full[:, 0], 0, width - 1), np.clip(full[:, 1], 0, height - 1),
         np.clip(full[:, 2], 0, width - 1), np.clip(full[:, 3], 0, height - 1)]
    )  # fmt: skip
    with np.errstate(invalid="ignore"):
        shown = _area(clipped) / np.maximum(_area(full), 1e-9)
        truncated = np.where(ahead.any(axis=1), 1 - shown, 1.0)
    return np.where(np.isfinite(clipped), clipped, 0.0), np.clip(
        np.nan_to_num(truncated, nan=1.0), 0, 1
    )


def read_key_values(path: Path) -> dict[str, np.ndarray]:
    """``key_values`` of a calibration file (``calib_cam_to_cam.txt`` …)."""
    return key_values(_read_text(path, "calibration"), path)


def read_poses(path: Path) -> np.ndarray:
    """(N, 4, 4) ``cam0_T_cami`` from an odometry-format ``poses.txt`` (12 numbers a line)."""
    return parse_poses(_read_text(path, "poses"), path)


def parse_poses(text: str, path: Path | str) -> np.ndarray:
    """(N, 4, 4) from the text of an odometry-format poses file."""
    try:
        values = np.array(
            [line.split() for line in text.splitlines() if line.strip()], dtype=np.float64
        )
    except ValueError as exc:
        raise KittiError(f"{path}: not KITTI poses (12 numbers a line): {exc}") from None
    if values.ndim != 2 or values.shape[1] != 12 or not np.isfinite(values).all():
        raise KittiError(
            f"{path}: every line of KITTI poses holds 12 finite numbers (3 × 4, row-major)"
        )
    poses = np.tile(np.eye(4), (len(values), 1, 1))
    poses[:, :3, :] = values.reshape(-1, 3, 4)
    return poses


def write_poses(path: Path, poses: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [" ".join(f"{v:.9e}" for v in pose[:3].ravel()) for pose in poses]
    path.write_text("".join(line + "\n" for line in lines))


def lidar_poses(camera_poses: np.ndarray, calibration: Calibration) -> np.ndarray:
    """(N, 4, 4) ``velo0_T_veloi``: the LiDAR's poses in the first frame's LiDAR frame, from
    the camera's ``cam0_T_cami``."""
    rect_T_velo = calibration.rect_T_velo
    return np.linalg.inv(rect_T_velo) @ camera_poses @ rect_T_velo


def boxes_in_lidar(labels: Labels, calibration: Calibration) -> np.ndarray:
    """(N, 7) the labels' boxes in the LiDAR frame."""
    return camera_to_lidar(labels.camera_box, calibration)


DEPTH_SCALE = 256.0
MAX_STORED_M = 65535 / DEPTH_SCALE


def write_depth_png(path: Path, depth_m: np.ndarray) -> None:
    """Depth (H, W) metres as KITTI's uint16 PNG; 0, negative, non-finite or beyond
    ``MAX_STORED_M`` (256 m) is stored as 0 (no measurement)."""
    import cv2

    depth = np.asarray(depth_m, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth must be (H, W), got {depth.shape}")
    valid = np.isfinite(depth) & (depth > 0) & (depth <= MAX_STORED_M)
    stored = np.where(valid, np.rint(np.where(valid, depth, 0) * DEPTH_SCALE), 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), stored.astype(np.uint16)):
        raise ValueError(f"{path}: could not write the PNG")


def read_depth_png(path: Path) -> np.ndarray:
    """(H, W) float32 metres from a KITTI depth PNG (0 = no measurement)."""
    import cv2

    stored = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if stored is None:
        raise ValueError(f"{path}: not a readable PNG")
    if stored.dtype != np.uint16 or stored.ndim != 2:
        raise ValueError(
            f"{path}: a depth PNG is one 16-bit channel (KITTI: metres × 256), this one is "
            f"{stored.dtype} with shape {stored.shape}"
        )
    return stored.astype(np.float32) / DEPTH_SCALE
