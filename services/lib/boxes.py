"""3D boxes in the LiDAR frame, vectorised over rows: ``(…, 7)`` float arrays
``x y z l w h yaw`` — the centre (metres), the length along the heading, the width across
it, the height (metres) and the heading about the LiDAR's z axis (radians, from x towards
y). KITTI's camera-frame boxes (``h w l x y z ry``, the bottom centre in the rectified
camera frame) convert through a calibration (``kitti.Calibration``).

The overlaps are the single-object tracking literature's (SC3D, P2B): the bird's-eye view
intersection of the two rotated rectangles times the overlap of their heights, over the
union of the volumes.
"""

from __future__ import annotations

import numpy as np

X, Y, Z, L, W, H, YAW = range(7)
BOX_FIELDS = ("x", "y", "z", "l", "w", "h", "yaw")


def wrap(angle_rad: np.ndarray) -> np.ndarray:
    """Angles in (−π, π]."""
    return np.pi - np.mod(np.pi - np.asarray(angle_rad, dtype=np.float64), 2 * np.pi)


def check_boxes(boxes: np.ndarray, what: str = "boxes") -> np.ndarray:
    """``boxes`` as a float64 (…, 7) array; ValueError naming the problem (shape, non-finite
    values, sizes that are not positive)."""
    array = np.asarray(boxes, dtype=np.float64)
    if array.shape[-1:] != (7,):
        raise ValueError(f"{what} must be (…, 7) rows of x y z l w h yaw, got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{what} hold non-finite values")
    if (array[..., L:YAW] <= 0).any():
        raise ValueError(f"{what} must have positive length, width and height")
    return array


def bev_corners(boxes: np.ndarray) -> np.ndarray:
    """(…, 4, 2) corners of the boxes seen from above, counter-clockwise (metres)."""
    boxes = np.asarray(boxes, dtype=np.float64)
    half_l, half_w = boxes[..., L, None] / 2, boxes[..., W, None] / 2
    local_x = np.array([1.0, -1.0, -1.0, 1.0]) * half_l
    local_y = np.array([1.0, 1.0, -1.0, -1.0]) * half_w
    c, s = np.cos(boxes[..., YAW, None]), np.sin(boxes[..., YAW, None])
    return np.stack(
        [
            boxes[..., X, None] + c * local_x - s * local_y,
            boxes[..., Y, None] + s * local_x + c * local_y,
        ],
        axis=-1,
    )


def corners(boxes: np.ndarray) -> np.ndarray:
    """(…, 8, 3) corners: the bottom four (counter-clockwise from above), then the top four."""
    boxes = np.asarray(boxes, dtype=np.float64)
    flat = bev_corners(boxes)
    bottom = boxes[..., Z, None] - boxes[..., H, None] / 2
    top = boxes[..., Z, None] + boxes[..., H, None] / 2
    heights = np.concatenate([np.repeat(bottom, 4, -1), np.repeat(top, 4, -1)], axis=-1)
    return np.concatenate([np.concatenate([flat, flat], axis=-2), heights[..., None]], axis=-1)


def to_box_frame(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """points : (N, ≥3) metres in the LiDAR frame → (N, 3) in the box's frame (origin at its
    centre, x along its heading, z up)."""
    box = np.asarray(box, dtype=np.float64)
    c, s = np.cos(box[YAW]), np.sin(box[YAW])
    shifted = np.asarray(points[:, :3], dtype=np.float64) - box[:3]
    return np.column_stack(
        [
            c * shifted[:, 0] + s * shifted[:, 1],
            -s * shifted[:, 0] + c * shifted[:, 1],
            shifted[:, 2],
        ]
    )


def from_box_frame(local: np.ndarray, box: np.ndarray) -> np.ndarray:
    """The inverse of ``to_box_frame``: (N, 3) box-frame points → the LiDAR frame."""
    box = np.asarray(box, dtype=np.float64)
    c, s = np.cos(box[YAW]), np.sin(box[YAW])
    return np.column_stack(
        [
            box[X] + c * local[:, 0] - s * local[:, 1],
            box[Y] + s * local[:, 0] + c * local[:, 1],
            box[Z] + local[:, 2],
        ]
    )


def inside(points: np.ndarray, box: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
    """(N,) bool: the points within ``box`` grown by ``margin_m`` on every side."""
    box = np.asarray(box, dtype=np.float64)
    reach = np.hypot(box[L], box[W]) / 2 + margin_m
    near = np.flatnonzero(
        (np.abs(points[:, 0] - box[X]) <= reach) & (np.abs(points[:, 1] - box[Y]) <= reach)
    )
    local = to_box_frame(points[near], box)
    out = np.zeros(len(points), dtype=bool)
    out[near] = (np.abs(local) <= box[L:YAW] / 2 + margin_m).all(axis=1)
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _inside_convex(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(P, K) bool: each of K points (P, K, 2) within its counter-clockwise quad (P, 4, 2)."""
    edges = np.roll(polygon, -1, axis=1) - polygon
    relative = points[:, :, None, :] - polygon[:, None, :, :]
    return (_cross(edges[:, None, :, :], relative) >= -1e-12).all(axis=2)


def bev_intersection_area(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P,) area (m²) where the rotated rectangles of box rows ``a`` and ``b`` (P, 7) overlap.

    The overlap of two convex quads is the convex hull of the corners of each inside the
    other and of their edges' crossings: at most 24 candidates per pair, ordered by angle
    around their mean, with the unused ones repeating the first so they add no area."""
    pa, pb = bev_corners(a), bev_corners(b)
    pairs = len(pa)
    a_start, a_edge = pa[:, :, None, :], (np.roll(pa, -1, axis=1) - pa)[:, :, None, :]
    b_start, b_edge = pb[:, None, :, :], (np.roll(pb, -1, axis=1) - pb)[:, None, :, :]
    denominator = _cross(a_edge, b_edge)
    parallel = np.abs(denominator) < 1e-12
    safe = np.where(parallel, 1.0, denominator)
    t = _cross(b_start - a_start, b_edge) / safe
    u = _cross(b_start - a_start, a_edge) / safe
    crossing = ~parallel & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    crossings = (a_start + t[..., None] * a_edge).reshape(pairs, 16, 2)
    candidates = np.concatenate([pa, pb, crossings], axis=1)
    valid = np.concatenate(
        [_inside_convex(pa, pb), _inside_convex(pb, pa), crossing.reshape(pairs, 16)], axis=1
    )
    count = valid.sum(axis=1)
    centre = (candidates * valid[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    angle = np.arctan2(
        candidates[..., 1] - centre[:, None, 1], candidates[..., 0] - centre[:, None, 0]
    )
    order = np.argsort(np.where(valid, angle, np.inf), axis=1)
    ordered = np.take_along_axis(candidates, order[..., None], axis=1)
    keep = np.take_along_axis(valid, order, axis=1)
    ordered = np.where(keep[..., None], ordered, ordered[:, :1, :])
    following = np.roll(ordered, -1, axis=1)
    area = 0.5 * np.abs(_cross(ordered, following).sum(axis=1))
    return np.where(count >= 3, area, 0.0)


def _pairs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    return a.reshape(-1, 7), b.reshape(-1, 7)


def bev_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Bird's-eye-view IoU of box rows ``a`` and ``b`` (broadcast against each other)."""
    shape = np.broadcast_shapes(np.shape(a), np.shape(b))[:-1]
    fa, fb = _pairs(a, b)
    overlap = bev_intersection_area(fa, fb)
    union = fa[:, L] * fa[:, W] + fb[:, L] * fb[:, W] - overlap
    return (overlap / np.maximum(union, 1e-12)).reshape(shape)


def iou_3d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3D IoU of box rows ``a`` and ``b`` (broadcast): BEV overlap × height overlap over
    the union of the volumes (the SOT benchmarks' overlap)."""
    shape = np.broadcast_shapes(np.shape(a), np.shape(b))[:-1]
    fa, fb = _pairs(a, b)
    top = np.minimum(fa[:, Z] + fa[:, H] / 2, fb[:, Z] + fb[:, H] / 2)
    bottom = np.maximum(fa[:, Z] - fa[:, H] / 2, fb[:, Z] - fb[:, H] / 2)
    overlap = bev_intersection_area(fa, fb) * np.maximum(top - bottom, 0.0)
    volumes = fa[:, L] * fa[:, W] * fa[:, H] + fb[:, L] * fb[:, W] * fb[:, H]
    return (overlap / np.maximum(volumes - overlap, 1e-12)).reshape(shape)


def centre_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance between the boxes' centres (metres), broadcast."""
    return np.linalg.norm(np.asarray(a)[..., :3] - np.asarray(b)[..., :3], axis=-1)


def transform_boxes(a_T_b: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """Boxes given in frame b → frame a by a rigid 4 × 4 transform whose rotation is about z
    (ego motion on a road): the heading turns by the transform's yaw."""
    boxes_b = np.asarray(boxes_b, dtype=np.float64)
    out = boxes_b.copy()
    out[..., :3] = boxes_b[..., :3] @ a_T_b[:3, :3].T + a_T_b[:3, 3]
    out[..., YAW] = wrap(boxes_b[..., YAW] + np.arctan2(a_T_b[1, 0], a_T_b[0, 0]))
    return out
