"""Training the learned car detector (``nets.BevDetector``) on labelled scans, and its ONNX
export — from scratch, or fine-tuning a model already trained (the shipped one, say) on
the user's own labelled scans.

Each step takes random windows (``window_cells`` square, 0.2 m cells) of the scans' front
views. A scan first receives cars cut from other training scans (``paste``: ground-truth
sampling, at plausible places where the labels speak, occlusion respected), then is
mirrored, turned (±10°) and scaled (±5 %) at random and thinned (up to a third of its
returns dropped). A car's centre is a Gaussian peak in the 0.8 m heatmap (CenterNet's focal
loss, α = 2, β = 4), and the cell under it learns the offset, height, log size and doubled
heading (L1). The loss looks only where the labels speak: inside the camera's field of
view (KITTI labels nothing outside it) and outside its DontCare regions, and not at vans
and trucks (neither car nor background) nor at cars with fewer than three returns
(nothing to see).

Fine-tuning starts from the model file's own weights with its batch norms folded into the
convolutions (a few scans make poor batch statistics) and a smaller step.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from services.lib import kitti
from services.lib.boxes import YAW, inside
from services.lib.nn.fit import Progress
from services.tracking.bev import CELL_M, CHANNELS, FULL_VIEW, STRIDE, Window, encode
from services.tracking.datasets import LabelledScan, data_fingerprint, labelled_scans, split_groups
from services.tracking.detect_learned import ARCHITECTURE, THRESHOLD
from services.tracking.ground import Ground, estimate_ground
from services.tracking.kinds import (
    DETECTOR_BATCH,
    DETECTOR_EPOCHS,
    DETECTOR_LEARNING_RATE,
    TrainParams,
)
from services.tracking.paste import CutCar, cut_cars, paste_cars

IMAGE_SIZE = (1242, 375)
MIN_RETURNS = 3
BANK_SCANS = 400
"""Cars are cut from at most this many scans of each source (a simulated set has thousands)."""
SETTINGS = TrainParams.model_fields


@dataclass(frozen=True)
class DetectorTrainConfig:
    epochs: int = DETECTOR_EPOCHS
    batch: int = DETECTOR_BATCH
    learning_rate: float = DETECTOR_LEARNING_RATE
    seed: int = SETTINGS["seed"].default
    threads: int = 2
    device: str = SETTINGS["device"].default
    window_cells: int = SETTINGS["window"].default
    frame_step: int = SETTINGS["frame_step"].default
    val_fraction: float = 0.1
    augment: bool = True
    paste: int = SETTINGS["paste"].default
    """The most cars pasted into a training scan (0: none)."""
    windows_per_epoch: int = SETTINGS["windows"].default
    """An epoch is at least this many windows: a few scans are seen many times, each time
    with other cars pasted, mirrored, turned and thinned."""
    initial: str | None = None
    """A model file of this architecture to fine-tune (None: train from scratch)."""
    threshold: float | None = None
    """The score from which the model's boxes are kept (in its metadata); None: the fine-tuned
    model's own, or ``THRESHOLD``."""


@dataclass(frozen=True)
class TrainingData:
    items: list[LabelledScan]
    cars: list[CutCar]
    """The cars pasted into training scans: cut from the training scans themselves and from
    any other sources given."""
    weights: np.ndarray | None
    """How likely each car is drawn: the training scans' own cars as a whole as likely as
    the other sources' (a few real cars are not drowned by thousands of simulated ones)."""
    grounds: dict[Path, Ground]
    """Each scan's ground, estimated once."""

    def ground(self, item: LabelledScan) -> Ground:
        if item.path not in self.grounds:
            self.grounds[item.path] = estimate_ground(kitti.read_velodyne(item.path))
        return self.grounds[item.path]


def labels_speak(xy: np.ndarray, item: LabelledScan) -> np.ndarray:
    """(N,) bool: ground-plane places (N, 2) the scan's labels cover — seen by camera 2 at a
    car's mid-height, and not in a DontCare region of its image."""
    points = np.column_stack([xy, np.full(len(xy), -0.9)])
    pixels, depth = item.calibration.velo_to_image(points)
    seen = (depth > 0.5) & (pixels[:, 0] >= 0) & (pixels[:, 0] < IMAGE_SIZE[0])
    for left, top, right, bottom in item.dont_care:
        seen &= ~(
            (pixels[:, 0] >= left)
            & (pixels[:, 0] <= right)
            & (pixels[:, 1] >= top)
            & (pixels[:, 1] <= bottom)
        )
    return seen


def car_bank(items: list[LabelledScan], seed: int) -> list[CutCar]:
    """Cars with their returns, cut from (at most ``BANK_SCANS`` of) ``items``."""
    rng = np.random.default_rng(seed)
    chosen = rng.permutation(len(items))[:BANK_SCANS]
    return [
        car
        for index in sorted(chosen)
        for car in cut_cars(kitti.read_velodyne(items[index].path), items[index].cars)
    ]


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


def sample(
    item: LabelledScan,
    rng: np.random.Generator,
    window_cells: int,
    augment: bool,
    data: TrainingData | None = None,
    paste: int = 0,
) -> tuple:
    """One training window of a scan: (image, heatmap, mask, centres, values); with
    ``data`` and ``paste``, up to that many of its cars pasted in first."""
    points = kitti.read_velodyne(item.path)
    cars = item.cars
    if augment and data is not None and paste > 0:
        points, pasted = paste_cars(
            points, item.objects, data.ground(item), data.cars, rng,
            int(rng.integers(0, paste + 1)), lambda centres: labels_speak(centres[:, :2], item),
            data.weights,
        )  # fmt: skip
        cars = np.concatenate([cars, pasted])
    seen = np.array([inside(points, box).sum() >= MIN_RETURNS for box in cars], dtype=bool)
    cars, ignored = cars[seen], np.concatenate([item.ignored, cars[~seen]])
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
    looked = labels_speak(grid @ np.linalg.inv(transform).T, item).reshape(len(xs), len(ys))
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
    data: TrainingData,
    index: np.ndarray,
    rng: np.random.Generator,
    config: DetectorTrainConfig,
    device: object,
    augment: bool,
) -> tuple:
    import torch

    samples = [
        sample(data.items[i], rng, config.window_cells, augment, data, config.paste) for i in index
    ]
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


def _shares(own: int, others: int) -> np.ndarray | None:
    """Draw weights giving each half of the bank (own, others) half the draws."""
    if not own or not others:
        return None
    return np.concatenate([np.full(own, 0.5 / own), np.full(others, 0.5 / others)])


def detector_network(initial: Path | None = None):  # noqa: ANN201 - a torch module
    """A fresh ``BevDetector``, or the one in the model file ``initial`` (its batch norms
    folded into its convolutions, as the file holds it)."""
    from services.lib.nn.onnx_io import fold_batch_norms, load_onnx_weights, read_model
    from services.tracking.nets import BevDetector

    if initial is None:
        return BevDetector()
    found = read_model(Path(initial))
    if found.metadata.get("architecture") != ARCHITECTURE:
        raise ValueError(
            f"{initial}: a {found.metadata.get('architecture')!r} model, not vista's car detector "
            f"({ARCHITECTURE}): nothing to fine-tune"
        )
    network = fold_batch_norms(BevDetector())
    load_onnx_weights(network, Path(initial))
    return network


def train_detector(
    folders: list[Path],
    out: Path,
    config: DetectorTrainConfig,
    *,
    validate_on: list[Path] | None = None,
    paste_from: list[Path] | None = None,
    licence: str | None = None,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
    sources: list[str] | None = None,
    command: str = "vista tracking train",
) -> dict:
    """Train on the labelled scans of ``folders`` (fine-tune ``config.initial`` when given),
    export to ``out`` (ONNX with its metadata) and return the metadata. Validation is on the
    labelled scans of ``validate_on`` (held out by the user) or else on a share of
    ``folders``' (whole runs of a drive; the best epoch on them is kept — on held-out scans,
    the last, so that nothing is chosen on them); cars are pasted from the training scans
    and from ``paste_from``'s. ``licence`` is the training data's, as the metadata should
    say it; ``command`` what built the model."""
    import torch

    from services.lib.nn.fit import fit
    from services.lib.nn.onnx_io import export_onnx

    say = progress or (lambda fraction, message: None)
    items = labelled_scans(folders, config.frame_step)
    if validate_on:
        held_out = labelled_scans(validate_on, 1)
        train_index = np.arange(len(items))
        val_index = np.arange(len(items), len(items) + len(held_out))
        items = items + held_out
    else:
        train_index, val_index = split_groups(
            items, [i.group for i in items], config.val_fraction, config.seed
        )
    if len(train_index) < 1 or len(val_index) < 1:
        raise ValueError(
            f"{len(items)} labelled scan(s) found: training needs at least one to learn from "
            "and one to validate on"
        )
    torch.manual_seed(config.seed)
    network = detector_network(Path(config.initial) if config.initial else None)
    threshold = config.threshold
    if threshold is None:
        threshold = _origin(Path(config.initial))["threshold"] if config.initial else THRESHOLD
    say(0.0, "cutting cars to paste" if config.paste else "reading the labels")
    extra = labelled_scans(paste_from, config.frame_step) if paste_from else []
    training = [items[i] for i in train_index]
    own = car_bank(training, config.seed) if config.paste else []
    others = car_bank(extra, config.seed) if config.paste else []
    data = TrainingData(items, own + others, _shares(len(own), len(others)), {})
    say(
        0.0,
        f"{len(train_index)} scans to train on ({sum(len(i.cars) for i in training)} cars, "
        f"{len(data.cars)} to paste), {len(val_index)} to validate",
    )
    held_out = [items[i] for i in val_index]
    before = _validation_scores(network.eval(), held_out, threshold) if config.initial else None
    modules = {"detector": network}

    def step(batch: tuple) -> tuple:
        images, *truth = batch
        return detector_loss(network(images), *truth)

    validation = [
        _batch(data, np.array([i]), np.random.default_rng(i), config, "cpu", augment=False)
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
                "data": data_fingerprint([i.path for i in items + extra]),
            },
            sort_keys=True,
        ).encode()
    ).hexdigest()
    epoch_index = np.resize(train_index, max(len(train_index), config.windows_per_epoch))
    result = fit(
        modules, step, validate, epoch_index,
        lambda index, rng, device: _batch(data, index, rng, config, device, config.augment),
        config, run=run, checkpoint_dir=checkpoint_dir, progress=progress,
        keep_best=not validate_on,
    )  # fmt: skip
    network.eval()
    scores = _validation_scores(network, held_out, threshold)
    metadata = {
        "architecture": ARCHITECTURE,
        "input": {
            "name": "bev",
            "channels": CHANNELS,
            "cell_m": CELL_M,
            "output_stride": STRIDE,
            "layout": "NCHW, H and W multiples of 16",
        },
        "threshold": threshold,
        "parameters": sum(p.numel() for p in network.parameters()),
        "training": {
            "data": sources or [_shown(f) for f in folders],
            "validated_on": [_shown(f) for f in validate_on or []],
            "cars_pasted_from": [_shown(f) for f in paste_from or []],
            "licence": licence,
            "fine_tuned_from": _origin(Path(config.initial)) if config.initial else None,
            "scans": {"train": len(train_index), "val": len(val_index)},
            "seed": config.seed,
            "epochs": config.epochs,
            "best_epoch": result.best_epoch,
            "seconds": round(result.seconds, 1),
            "history": result.history,
            "command": command,
        },
        "validation": {
            "scan_names": [item.name for item in held_out],
            "held_out": bool(validate_on),
            **scores,
            **({"before_fine_tuning": before} if before is not None else {}),
        },
    }
    example = encode(np.zeros((1, 4), np.float32), Window.around((0, -12.8, 25.6, 12.8)))[None]
    export_onnx(
        network, example, out, metadata, input_name="bev", output_name="heads", free_axes=(0, 2, 3)
    )
    say(1.0, "exported to ONNX with its validation in the metadata")
    return metadata


def _shown(folder: Path) -> str:
    """A folder as the metadata names it: relative to the working folder when it is near
    (``../shared/data/…``, ``bench-results/…``), else as given."""
    relative = os.path.relpath(Path(folder).resolve())
    return relative if relative.count("..") <= 2 else str(folder)


def _origin(initial: Path) -> dict:
    """What a fine-tuned model started from: the file and what its metadata says of it."""
    from services.lib.nn.onnx_io import read_model

    metadata = read_model(initial).metadata
    training = metadata.get("training", {})
    return {
        "file": initial.name,
        "data": training.get("data"),
        "licence": training.get("licence"),
        "threshold": metadata.get("threshold", THRESHOLD),
    }


def _validation_scores(network, items: list[LabelledScan], threshold: float) -> dict:  # noqa: ANN001 - a torch module
    """Recall of cars within 40 m and precision in the camera's view on the validation
    scans' full views, at ``threshold``."""
    import torch

    from services.tracking.detect_learned import decode
    from services.tracking.detection_eval import combine, match_scan

    tallies = []
    window = Window.around(FULL_VIEW)
    for item in items[:60]:
        points = kitti.read_velodyne(item.path)
        with torch.no_grad():
            output = network(torch.from_numpy(encode(points, window)[None]))[0].numpy()
        found = decode(output, window, threshold)
        tallies.append(match_scan(found, item.labels, item.calibration).tally())
    return combine(tallies, 40.0, threshold).document() if tallies else {}
