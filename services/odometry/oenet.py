"""OE-Net exactly as the thesis's Table 6.1: two branches on two consecutive 64 × 64 grey
frames — translation (17/9/5 kernels, 32/64/128 channels, FC 1024/256/2) and rotation
(5/5/5 kernels, FC 256/32/1) — concatenated into (δx mm, δy mm, δθ °) and trained on the
mean squared error by SGD with momentum 0.9 in batches of 256.

The table gives no activations after the fully connected layers; ReLU follows each but the
last. The 64 × 64 inputs are the frames' centre squares, area-averaged (the thesis
downsampled its frames; a square keeps the floor's geometry), each scaled to zero mean and
unit spread; the targets are learned standardised (``services.lib.nn.regression``), the exported
model answers in mm and degrees.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from services.odometry import se2
from services.odometry.camera import FloorCamera
from services.odometry.frames import frame_files, read_frames
from services.odometry.tum import read_tum

INPUT_SIDE = 64
ARCHITECTURE = "oenet"
OUTPUT_COLUMNS = ("dx_mm", "dy_mm", "dtheta_deg")


TRANSLATION_BRANCH = (((17, 2), (9, 2), (5, 1)), (1024, 256, 2))
"""Table 6.1: (kernel, padding) of Conv1–3 (stride 1, then ReLU and 2 × 2 max-pooling;
32, 64, 128 channels) and the sizes of FC1–3."""
ROTATION_BRANCH = (((5, 2), (5, 2), (5, 2)), (256, 32, 1))


def _branch(convolutions: tuple, sizes: tuple):  # noqa: ANN202 - a torch.nn.Sequential
    from torch import nn

    layers: list = []
    channels, side = 2, INPUT_SIDE
    for (kernel, padding), out in zip(convolutions, (32, 64, 128), strict=True):
        layers += [nn.Conv2d(channels, out, kernel, stride=1, padding=padding), nn.ReLU()]
        layers.append(nn.MaxPool2d(2, 2))
        channels, side = out, (side + 2 * padding - kernel + 1) // 2
    layers.append(nn.Flatten())
    width = channels * side * side
    for k, size in enumerate(sizes):
        layers.append(nn.Linear(width, size))
        if k < len(sizes) - 1:
            layers.append(nn.ReLU())
        width = size
    return nn.Sequential(*layers)


def network():  # noqa: ANN201 - a torch.nn.Module (torch imported inside)
    import torch
    from torch import nn

    class OENet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.translation = _branch(*TRANSLATION_BRANCH)
            self.rotation = _branch(*ROTATION_BRANCH)

        def forward(self, pair: torch.Tensor) -> torch.Tensor:
            return torch.cat([self.translation(pair), self.rotation(pair)], dim=1)

    net = OENet()
    # He's initialisation (each ReLU layer keeps its signal's size); each branch's last layer
    # starts at zero, so training starts from the targets' mean instead of noise
    for layer in net.modules():
        if isinstance(layer, nn.Conv2d | nn.Linear):
            nn.init.kaiming_normal_(layer.weight, nonlinearity="relu")
            nn.init.zeros_(layer.bias)
    for branch in (net.translation, net.rotation):
        nn.init.zeros_(branch[-1].weight)
    return net


def network_input(frame: np.ndarray) -> np.ndarray:
    """A frame as one 64 × 64 input channel: its centre square, area-averaged, scaled to
    zero mean and unit spread (a brighter light changes nothing)."""
    rows, cols = frame.shape
    side = min(rows, cols)
    top, left = (rows - side) // 2, (cols - side) // 2
    square = frame[top : top + side, left : left + side]
    small = cv2.resize(square, (INPUT_SIDE, INPUT_SIDE), interpolation=cv2.INTER_AREA)
    small = small.astype(np.float32)
    return (small - small.mean()) / (small.std() + 1.0)


def pairs_of(folder: Path) -> tuple[np.ndarray, np.ndarray, FloorCamera]:
    """A simulated sequence (frames/, camera.json, truth.tum) as network inputs
    (N−1, 2, 64, 64) and targets (N−1, 3): δx mm, δy mm, δθ °."""
    import json

    camera = FloorCamera.from_document(json.loads((folder / "camera.json").read_text()))
    truth = read_tum(folder / "truth.tum")
    files = frame_files(folder / "frames")
    if len(files) != len(truth):
        raise ValueError(f"{folder}: {len(files)} frames but {len(truth)} poses in truth.tum")
    small = np.stack([network_input(f) for f in read_frames(files, camera)])
    inputs = np.stack([small[:-1], small[1:]], axis=1)
    steps = se2.relative(truth.pose)
    targets = np.column_stack([steps[:, 0], steps[:, 1], np.degrees(steps[:, 2])])
    return inputs, targets.astype(np.float32), camera


def train_oenet(
    folders: list[Path],
    out: Path,
    config,  # noqa: ANN001 - services.lib.nn.regression.TrainConfig
    *,
    checkpoint_dir: Path | None = None,
    sources: list[str] | None = None,
    progress=None,  # noqa: ANN001 - (fraction, message) -> None
) -> dict:
    """Train OE-Net on the pairs of simulated sequences, export it to ``out`` (ONNX, checked
    against torch) and return its metadata; ``sources`` names the sequences in it (default:
    their folders)."""
    import torch

    from services.lib.nn.onnx_io import export_onnx
    from services.lib.nn.regression import train

    say = progress or (lambda fraction, message: None)
    parts = [pairs_of(folder) for folder in folders]
    squares = {round(square_mm(camera), 3) for _, _, camera in parts}
    if len(squares) > 1:
        raise ValueError(
            "the sequences' cameras see floor squares of different sizes "
            f"({', '.join(f'{side} mm' for side in sorted(squares))}): train on one camera"
        )
    inputs = np.concatenate([p[0] for p in parts])
    targets = np.concatenate([p[1] for p in parts])
    say(0.0, f"{len(inputs)} pairs from {len(folders)} sequence(s)")
    torch.manual_seed(config.seed)  # the initial weights too
    model = network()
    result = train(model, inputs, targets, config, checkpoint_dir=checkpoint_dir, progress=say)
    metadata = {
        "architecture": ARCHITECTURE,
        "task": "floor-camera odometry: relative planar motion of two consecutive frames",
        "input": {
            "name": "pair",
            "shape": ["batch", 2, INPUT_SIDE, INPUT_SIDE],
            "dtype": "float32",
            "content": "the two frames' centre squares area-averaged to 64 × 64, each "
            "scaled to zero mean and unit spread (grey levels / (std + 1))",
        },
        "output": {"name": "motion", "columns": list(OUTPUT_COLUMNS)},
        "camera": parts[0][2].document(),
        "training": {
            "sequences": sources or [str(folder) for folder in folders],
            "pairs": int(len(inputs)),
            "epochs": result.epochs_run,
            "batch": config.batch,
            "learning_rate": config.learning_rate,
            "momentum": config.momentum,
            "seed": config.seed,
            "seconds": round(result.seconds, 1),
            "history": result.history,
        },
        "metrics": {
            "best_epoch": result.best_epoch,
            "val_loss_standardised": result.best_val_loss,
            "val_rmse": dict(zip(OUTPUT_COLUMNS, result.val_rmse, strict=True)),
            "test_rmse": (
                dict(zip(OUTPUT_COLUMNS, result.test_rmse, strict=True))
                if result.test_rmse is not None
                else None
            ),
            "split": result.split,
        },
    }
    difference = export_onnx(
        result.model, inputs[:4], out, metadata, input_name="pair", output_name="motion"
    )
    say(1.0, f"exported {out.name} (onnxruntime vs torch: {difference:.1e})")
    return metadata


def oenet_motions(
    model_path: Path, frames: Iterable[np.ndarray], camera: FloorCamera, threads: int
) -> np.ndarray:
    """(N−1, 3) motions (mm, mm, rad) of consecutive frames by an exported OE-Net; its
    translation rescaled when this camera's floor square differs from the training
    camera's. Only each frame's 64 × 64 input is kept."""
    from services.lib.nn.onnx_io import read_model, session

    model = read_model(model_path)
    if model.metadata.get("architecture") != ARCHITECTURE:
        raise ValueError(
            f"{model_path}: a {model.metadata.get('architecture')!r} model, not OE-Net"
        )
    scale = _scale(camera, model.metadata)
    small = np.stack([network_input(f) for f in frames])
    inputs = np.stack([small[:-1], small[1:]], axis=1)
    runner = session(model_path, threads=threads)
    out = np.concatenate(
        [runner.run(None, {"pair": inputs[k : k + 256]})[0] for k in range(0, len(inputs), 256)]
    )
    return np.column_stack([out[:, 0] * scale, out[:, 1] * scale, np.radians(out[:, 2])])


def oenet_sigma(model_path: Path, camera: FloorCamera) -> np.ndarray:
    """(3,) the expected error of one motion (mm, mm, rad): the model's test RMSE (its
    validation RMSE when it was trained without a test set), scaled to ``camera``."""
    from services.lib.nn.onnx_io import read_model

    metadata = read_model(model_path).metadata
    metrics = metadata.get("metrics") or {}
    rmse = metrics.get("test_rmse") or metrics.get("val_rmse")
    if not isinstance(rmse, dict):
        raise ValueError(
            f"{model_path}: the model's metadata has no RMSE per motion component: retrain it "
            "with `vista odometry train`"
        )
    scale = _scale(camera, metadata)
    return np.array([rmse["dx_mm"] * scale, rmse["dy_mm"] * scale, np.radians(rmse["dtheta_deg"])])


def square_mm(camera: FloorCamera) -> float:
    """The side of the floor square the network sees (the frame's centre square)."""
    return camera.mm_per_px * min(camera.width, camera.height)


def _scale(camera: FloorCamera, metadata: dict) -> float:
    """How much more floor one input pixel covers with ``camera`` than in training."""
    if "camera" not in metadata:
        raise ValueError("the model's metadata has no training camera: retrain it")
    return square_mm(camera) / square_mm(FloorCamera.from_document(metadata["camera"]))


def training_summary(metadata: dict) -> str:
    """One line on a trained model: its data, time and errors per column."""
    training, metrics = metadata["training"], metadata["metrics"]

    def columns(rmse: dict) -> str:
        return f"δx {rmse['dx_mm']:.4f} mm, δy {rmse['dy_mm']:.4f} mm, δθ {rmse['dtheta_deg']:.4f}°"

    line = (
        f"{training['pairs']} pairs, {training['epochs']} epochs in {training['seconds']:.0f} s "
        f"(best epoch {metrics['best_epoch']}); validation RMSE {columns(metrics['val_rmse'])}"
    )
    if metrics.get("test_rmse"):
        line += f"; test RMSE {columns(metrics['test_rmse'])}"
    return line
