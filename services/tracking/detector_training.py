"""Training the learned car detector (``nets.BevDetector``) on labelled scans, and its ONNX
export.

Each step takes random windows (``window_cells`` square, 0.2 m cells) of the scans' front
views, each scan mirrored, turned (±10°) and scaled (±5 %) at random and thinned (up to a
third of its returns dropped). A car's centre is a
Gaussian peak in the 0.8 m heatmap (CenterNet's focal loss, α = 2, β = 4), and the cell
under it learns the offset, height, log size and doubled heading (L1). The loss looks only
where the labels speak: inside the camera's field of view (KITTI labels nothing outside it),
and not at vans and trucks (neither car nor background) nor at cars with fewer than three
returns (nothing to see).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from services.nn.fit import Progress
from services.tracking import kitti
from services.tracking.bev import CELL_M, CHANNELS, FULL_VIEW, STRIDE, Window, encode
from services.tracking.boxes import YAW, inside
from services.tracking.datasets import LabelledScan, data_fingerprint, labelled_scans, split_groups
from services.tracking.detect_learned import ARCHITECTURE, THRESHOLD
from services.tracking.kinds import DETECTOR_EPOCHS

IMAGE_WIDTH = 1242
MIN_RETURNS = 3


@dataclass(frozen=True)
class DetectorTrainConfig:
    epochs: int = DETECTOR_EPOCHS
    batch: int = 8
    learning_rate: float = 2e-3
    seed: int = 0
    threads: int = 2
    device: str = "auto"
    window_cells: int = 224
    frame_step: int = 2
    val_fraction: float = 0.1
    augment: bool = True


def _similarity(rng: np.random.Generator, augment: bool) -> np.ndarray:
    """(2, 2) a random mirror, turn and scale of the ground plane."""
    if not augment:
        return np.eye(2)
    angle = rng.uniform(-np.radians(10), np.radians(10))
    scale = rng.uniform(0.95, 1.05)
    mirror = np.diag([1.0, -1.0 if rng.uniform() < 0.5 else 1.0])
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return scale * turn @ mirror


def _moved_boxes(boxes: np.ndarray, transform: np.ndarray) -> np.ndarray:
    out = boxes.copy()
    out[:, :2] = boxes[:, :2] @ transform.T
    scale = np.sqrt(abs(np.linalg.det(transform)))
    out[:, 3:6] *= scale
    heading = np.column_stack([np.cos(boxes[:, YAW]), np.sin(boxes[:, YAW])]) @ transform.T
    out[:, YAW] = np.arctan2(heading[:, 1], heading[:, 0])
    return out


def _in_view(xy: np.ndarray, calibration: kitti.Calibration) -> np.ndarray:
    """(N,) bool: ground-plane points (N, 2) at a car's mid-height seen by camera 2."""
    points = np.column_stack([xy, np.full(len(xy), -0.9)])
    pixels, depth = calibration.velo_to_image(points)
    return (depth > 0.5) & (pixels[:, 0] >= 0) & (pixels[:, 0] < IMAGE_WIDTH)


def targets(
    cars: np.ndarray, ignored: np.ndarray, window: Window, looked: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The heatmap (h, w), the loss mask (h, w; 0 where the labels do not speak), the centre
    cells (K, 2) and their regression targets (K, 8) of one window; ``looked`` (h, w) is
    where the labels cover (the camera's view)."""
    cell = CELL_M * STRIDE
    h, w = window.rows // STRIDE, window.cols // STRIDE
    heat = np.zeros((h, w), dtype=np.float32)
    mask = looked.astype(np.float32)
    xs, ys = window.cell_centres(STRIDE)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    centres, values = [], []
    for box in ignored:
        mask[_footprint(box, gx, gy, 1.0)] = 0.0
    for box in cars:
        row = int(np.floor((box[0] - window.x0_m) / cell))
        col = int(np.floor((box[1] - window.y0_m) / cell))
        sigma = max(0.6, 0.25 * min(box[3], box[4]))
        heat = np.maximum(heat, np.exp(-((gx - box[0]) ** 2 + (gy - box[1]) ** 2) / (2 * sigma**2)))
        if 0 <= row < h and 0 <= col < w:
            heat[row, col] = 1.0
            centres.append((row, col))
            values.append(
                [(box[0] - window.x0_m) / cell - row, (box[1] - window.y0_m) / cell - col, box[2],
                 *np.log(box[3:6]), np.sin(2 * box[YAW]), np.cos(2 * box[YAW])]
            )  # fmt: skip
    return (
        heat,
        mask,
        np.array(centres, dtype=np.int64).reshape(-1, 2),
        np.array(values, dtype=np.float32).reshape(-1, 8),
    )


def _footprint(box: np.ndarray, gx: np.ndarray, gy: np.ndarray, margin_m: float) -> np.ndarray:
    c, s = np.cos(box[YAW]), np.sin(box[YAW])
    dx, dy = gx - box[0], gy - box[1]
    return (np.abs(c * dx + s * dy) <= box[3] / 2 + margin_m) & (
        np.abs(-s * dx + c * dy) <= box[4] / 2 + margin_m
    )


def sample(item: LabelledScan, rng: np.random.Generator, window_cells: int, augment: bool) -> tuple:
    """One training window of a scan: (image, heatmap, mask, centres, values)."""
    points = kitti.read_velodyne(item.path)
    seen = np.array([inside(points, box).sum() >= MIN_RETURNS for box in item.cars], dtype=bool)
    cars, ignored = item.cars[seen], np.concatenate([item.ignored, item.cars[~seen]])
    transform = _similarity(rng, augment)
    if augment:  # a sparser sensor, or a darker day: up to a third of the returns lost
        points = points[rng.uniform(size=len(points)) < rng.uniform(0.67, 1.0)]
    moved = points.copy()
    moved[:, :2] = points[:, :2] @ transform.T
    size_m = window_cells * CELL_M
    x0 = (
        rng.uniform(FULL_VIEW[0] - 4.0, FULL_VIEW[2] - size_m + 4.0)
        if augment
        else (FULL_VIEW[0] + FULL_VIEW[2] - size_m) / 2
    )
    y0 = rng.uniform(FULL_VIEW[1], FULL_VIEW[3] - size_m) if augment else -size_m / 2
    window = Window.around((x0, y0, x0 + size_m - 1e-6, y0 + size_m - 1e-6))
    xs, ys = window.cell_centres(STRIDE)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    looked = _in_view(grid @ np.linalg.inv(transform).T, item.calibration).reshape(len(xs), len(ys))
    heat, mask, centres, values = targets(
        _moved_boxes(cars, transform), _moved_boxes(ignored, transform), window, looked
    )
    return encode(moved, window), heat, mask, centres, values


def detector_loss(output, heat, mask, centres, values):  # noqa: ANN001, ANN201 - torch tensors
    """CenterNet's focal loss on the heatmap and L1 on the centre cells' regressions."""
    import torch

    probability = torch.sigmoid(output[:, 0]).clamp(1e-4, 1 - 1e-4)
    positive = (heat == 1).float()
    negative_weight = (1 - heat) ** 4 * mask * (1 - positive)
    focal = -(
        positive * (1 - probability) ** 2 * torch.log(probability)
        + negative_weight * probability**2 * torch.log(1 - probability)
    ).sum() / positive.sum().clamp(min=1)
    if len(centres):
        predicted = output[centres[:, 0], 1:, centres[:, 1], centres[:, 2]]
        regression = (predicted - values).abs().mean(dim=0)
        weights = torch.tensor(
            [1, 1, 1, 1, 1, 1, 0.5, 0.5], dtype=output.dtype, device=output.device
        )
        box_loss = (regression * weights).sum()
    else:
        box_loss = output.sum() * 0.0
    return focal + box_loss, {"focal": float(focal.detach()), "box": float(box_loss.detach())}


def _batch(
    items: list[LabelledScan],
    index: np.ndarray,
    rng: np.random.Generator,
    config: DetectorTrainConfig,
    device: object,
    augment: bool,
) -> tuple:
    import torch

    samples = [sample(items[i], rng, config.window_cells, augment) for i in index]
    images = torch.from_numpy(np.stack([s[0] for s in samples])).to(device)
    heat = torch.from_numpy(np.stack([s[1] for s in samples])).to(device)
    mask = torch.from_numpy(np.stack([s[2] for s in samples])).to(device)
    centres = torch.from_numpy(
        np.concatenate(
            [np.column_stack([np.full(len(s[3]), k), s[3]]) for k, s in enumerate(samples)]
        ).astype(np.int64)
    ).to(device)
    values = torch.from_numpy(np.concatenate([s[4] for s in samples])).to(device)
    return images.contiguous(memory_format=torch.channels_last), heat, mask, centres, values


def train_detector(
    folders: list[Path],
    out: Path,
    config: DetectorTrainConfig,
    *,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
    sources: list[str] | None = None,
) -> dict:
    """Train on the labelled scans of ``folders``, export to ``out`` (ONNX with its
    metadata) and return the metadata."""
    import torch

    from services.nn.fit import fit
    from services.nn.onnx_io import export_onnx
    from services.tracking.nets import BevDetector

    items = labelled_scans(folders, config.frame_step)
    if len(items) < 2:
        raise ValueError(f"{len(items)} labelled scan(s) found: training needs at least 2")
    train_index, val_index = split_groups(
        items, [i.group for i in items], config.val_fraction, config.seed
    )
    torch.manual_seed(config.seed)
    network = BevDetector()
    say = progress or (lambda fraction, message: None)
    say(
        0.0,
        f"{len(train_index)} scans to train on, {len(val_index)} to validate ({sum(len(i.cars) for i in items)} cars)",
    )
    modules = {"detector": network}

    def step(batch: tuple) -> tuple:
        images, *truth = batch
        return detector_loss(network(images), *truth)

    validation = [
        _batch(items, np.array([i]), np.random.default_rng(i), config, "cpu", augment=False)
        for i in val_index[:64]
    ]

    def validate() -> float:
        return float(np.mean([detector_loss(network(v[0]), *v[1:])[0].item() for v in validation]))

    run = hashlib.sha256(
        json.dumps(
            {
                "config": {
                    k: v
                    for k, v in asdict(config).items()
                    if k not in ("threads", "device", "epochs")
                },
                "data": data_fingerprint([i.path for i in items]),
            },
            sort_keys=True,
        ).encode()
    ).hexdigest()
    result = fit(
        modules, step, validate, train_index,
        lambda index, rng, device: _batch(items, index, rng, config, device, config.augment),
        config, run=run, checkpoint_dir=checkpoint_dir, progress=progress,
    )  # fmt: skip
    network.eval()
    scores = _validation_scores(network, [items[i] for i in val_index])
    metadata = {
        "architecture": ARCHITECTURE,
        "input": {
            "name": "bev",
            "channels": CHANNELS,
            "cell_m": CELL_M,
            "output_stride": STRIDE,
            "layout": "NCHW, H and W multiples of 16",
        },
        "threshold": THRESHOLD,
        "parameters": sum(p.numel() for p in network.parameters()),
        "training": {
            "data": sources or [str(f) for f in folders],
            "scans": {"train": len(train_index), "val": len(val_index)},
            "epochs": config.epochs,
            "best_epoch": result.best_epoch,
            "seconds": round(result.seconds, 1),
            "history": result.history,
            "command": "vista track train detector",
        },
        "validation": scores,
    }
    example = encode(np.zeros((1, 4), np.float32), Window.around((0, -12.8, 25.6, 12.8)))[None]
    export_onnx(
        network, example, out, metadata, input_name="bev", output_name="heads", free_axes=(0, 2, 3)
    )
    say(1.0, f"wrote {out}")
    return metadata


def _validation_scores(network, items: list[LabelledScan]) -> dict:  # noqa: ANN001 - a torch module
    """Recall of cars within 40 m and precision in the camera's view on the validation
    scans' full views, at the default threshold."""
    import torch

    from services.tracking.detect_learned import decode
    from services.tracking.detection_eval import combine, tally_scan

    tallies = []
    window = Window.around(FULL_VIEW)
    for item in items[:60]:
        points = kitti.read_velodyne(item.path)
        with torch.no_grad():
            output = network(torch.from_numpy(encode(points, window)[None]))[0].numpy()
        found = decode(output, window)
        labels = _as_labels(item)
        tallies.append(tally_scan(found, labels, item.calibration))
    return combine(tallies, 40.0, THRESHOLD).document() if tallies else {}


def _as_labels(item: LabelledScan) -> kitti.Labels:
    boxes = np.concatenate([item.cars, item.ignored])
    count = len(boxes)
    return kitti.Labels(
        frame=np.zeros(count, int),
        track_id=np.full(count, -1),
        type=("Car",) * len(item.cars) + ("Van",) * len(item.ignored),
        truncated=np.zeros(count),
        occluded=np.zeros(count, int),
        alpha=np.zeros(count),
        bbox=np.zeros((count, 4)),
        camera_box=kitti.lidar_to_camera(boxes, item.calibration),
        score=np.full(count, np.nan),
    )
