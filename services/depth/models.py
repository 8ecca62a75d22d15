"""Depth models as ONNX files, vista's own or the user's, run with onnxruntime.

A model maps an image to depth, disparity or Monodepth2's sigmoid disparity. What it expects
and answers is its *spec*: for vista's models the ``vista`` metadata inside the file; for
anyone else's, a JSON file beside it with the same stem (``teacher.onnx`` →
``teacher.json``)::

    {"input":  {"width": 640, "height": 192,      # the size the model takes
                "range": 1.0,                      # pixel values 0..range (1 or 255)
                "mean": [0.0, 0.0, 0.0],           # subtracted per channel (after range)
                "std": [1.0, 1.0, 1.0],            # divided per channel
                "channels": "RGB",                 # or "BGR"
                "layout": "NCHW"},                 # or "NHWC"
     "output": {"kind": "sigmoid_disparity",       # depth | disparity | sigmoid_disparity
                "scale": 1.0,                      # depth: metres per unit;
                                                   # disparity: depth = scale / output
                "min_depth_m": 0.1,                # sigmoid_disparity's range (Monodepth2)
                "max_depth_m": 100.0}}

Only "input.width", "input.height" and "output.kind" are required. The model's first output
is the map (N, 1, H, W), (N, H, W) or (N, H, W, 1); outputs named ``encoder`` and
``decoder`` (feature maps, N × C × h × w), when present, are the teacher's intermediate
features that vista's distillation can learn from.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from services.lib.nn.onnx_io import read_model, session

OUTPUT_KINDS = ("depth", "disparity", "sigmoid_disparity")
FEATURE_OUTPUTS = ("encoder", "decoder")
PACKAGED = Path(__file__).resolve().parent / "models" / "depth.onnx"
"""The model vista ships (``default_model.build_default_model`` builds it)."""


def default_model() -> Path:
    """The packaged model; ValueError saying how to get one when this installation has none."""
    if not PACKAGED.is_file():
        raise ValueError(
            f"{PACKAGED}: this installation ships no depth model; build it with `vista depth "
            "build-default` or give one with --model"
        )
    return PACKAGED


@dataclass(frozen=True)
class ModelSpec:
    width: int
    height: int
    output_kind: str
    value_range: float = 1.0
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    channels: str = "RGB"
    layout: str = "NCHW"
    scale: float = 1.0
    min_depth_m: float = 0.1
    max_depth_m: float = 100.0
    metadata: dict = field(default_factory=dict)
    """Everything the file or side-car said (vista's models: architecture, training, metrics)."""

    @classmethod
    def from_json(cls, data: dict, where: str) -> ModelSpec:
        try:
            given, answer = data["input"], data["output"]
            spec = cls(
                width=int(given["width"]),
                height=int(given["height"]),
                output_kind=str(answer["kind"]),
                value_range=float(given.get("range", 1.0)),
                mean=tuple(float(v) for v in given.get("mean", (0.0, 0.0, 0.0))),
                std=tuple(float(v) for v in given.get("std", (1.0, 1.0, 1.0))),
                channels=str(given.get("channels", "RGB")),
                layout=str(given.get("layout", "NCHW")),
                scale=float(answer.get("scale", 1.0)),
                min_depth_m=float(answer.get("min_depth_m", 0.1)),
                max_depth_m=float(answer.get("max_depth_m", 100.0)),
                metadata=data,
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(
                f"{where}: not a depth model spec (input.width, input.height, output.kind): {exc!r}"
            ) from None
        problems = []
        if spec.output_kind not in OUTPUT_KINDS:
            problems.append(
                f"output.kind {spec.output_kind!r} is not one of {', '.join(OUTPUT_KINDS)}"
            )
        if spec.channels not in ("RGB", "BGR"):
            problems.append(f"input.channels {spec.channels!r} is not RGB or BGR")
        if spec.layout not in ("NCHW", "NHWC"):
            problems.append(f"input.layout {spec.layout!r} is not NCHW or NHWC")
        if spec.width < 8 or spec.height < 8 or spec.value_range <= 0 or min(spec.std) <= 0:
            problems.append("input size ≥ 8 × 8, range > 0 and std > 0 are required")
        if len(spec.mean) != 3 or len(spec.std) != 3:
            problems.append("input.mean and input.std have three values")
        if not 0 < spec.min_depth_m < spec.max_depth_m or spec.scale <= 0:
            problems.append("0 < min_depth_m < max_depth_m and scale > 0 are required")
        if problems:
            raise ValueError(f"{where}: " + "; ".join(problems))
        return spec


def read_spec(path: Path) -> ModelSpec:
    """A model file's spec: vista's metadata, else the side-car JSON beside it."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such model file")
    try:
        return ModelSpec.from_json(read_model(path).metadata, str(path))
    except ValueError as exc:
        if "without vista's metadata" not in str(exc):
            raise
    side = path.with_suffix(".json")
    if not side.is_file():
        raise ValueError(
            f"{path}: an ONNX model of someone else's needs its spec in {side} (see `vista depth --help`)"
        )
    try:
        data = json.loads(side.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{side}: not JSON ({exc})") from None
    return ModelSpec.from_json(data, str(side))


@dataclass(frozen=True)
class Prediction:
    depth_m: np.ndarray
    """(N, H, W) float32 at the model's input size."""
    features: dict[str, np.ndarray]
    """The model's ``encoder`` / ``decoder`` outputs, when it has them and they were asked for."""


class DepthModel:
    """An ONNX depth model in onnxruntime on ``threads`` threads."""

    def __init__(self, path: Path, threads: int = 1) -> None:
        self.path = Path(path)
        self.spec = read_spec(self.path)
        try:
            self.session = session(self.path, threads)
        except Exception as exc:  # onnxruntime raises its own types for a bad graph
            raise ValueError(f"{path}: onnxruntime cannot load it ({exc})") from None
        self.input_name = self.session.get_inputs()[0].name
        self.output_names = [o.name for o in self.session.get_outputs()]
        self.feature_names = tuple(n for n in FEATURE_OUTPUTS if n in self.output_names)

    def prepare(self, images: np.ndarray) -> np.ndarray:
        """(N, H, W, 3) uint8 RGB at the model's size → the model's input array."""
        spec = self.spec
        if images.shape[1:3] != (spec.height, spec.width):
            raise ValueError(
                f"images are {images.shape[2]} × {images.shape[1]}, the model takes {spec.width} × {spec.height}"
            )
        x = images.astype(np.float32) * (spec.value_range / 255.0)
        if spec.channels == "BGR":
            x = x[..., ::-1]
        x = (x - np.array(spec.mean, np.float32)) / np.array(spec.std, np.float32)
        if spec.layout == "NCHW":
            x = x.transpose(0, 3, 1, 2)
        return np.ascontiguousarray(x)

    def to_depth(self, raw: np.ndarray) -> np.ndarray:
        """The model's first output as (N, H, W) depth in metres; ValueError when any of it
        is not finite (a depth map with holes must not pass for a measurement)."""
        spec = self.spec
        out = np.asarray(raw, np.float32)
        if out.ndim == 4:
            out = out[:, 0] if out.shape[1] == 1 else out[..., 0]
        if out.ndim != 3:
            raise ValueError(
                f"{self.path}: its first output has shape {raw.shape}, not a depth map"
            )
        if spec.output_kind == "depth":
            depth = out * spec.scale
        elif spec.output_kind == "disparity":
            depth = spec.scale / np.maximum(out, 1e-6)
        else:
            low, high = 1 / spec.max_depth_m, 1 / spec.min_depth_m
            depth = 1 / (low + (high - low) * out)
        broken = ~np.isfinite(depth)
        if broken.any():
            # e.g. an int8 model whose calibration did not cover these images' activations
            raise ValueError(
                f"{self.path}: the model answered no valid depth (NaN or infinite) for "
                f"{broken.mean():.1%} of the pixels"
            )
        return depth

    def predict(self, images: np.ndarray, *, features: bool = False, batch: int = 4) -> Prediction:
        """Depth for (N, H, W, 3) uint8 RGB images at the model's size."""
        wanted = [self.output_names[0]] + (list(self.feature_names) if features else [])
        depths, maps = [], {name: [] for name in wanted[1:]}
        for first in range(0, len(images), batch):
            answers = self.session.run(
                wanted, {self.input_name: self.prepare(images[first : first + batch])}
            )
            depths.append(self.to_depth(answers[0]))
            for name, answer in zip(wanted[1:], answers[1:], strict=True):
                maps[name].append(answer)
        return Prediction(np.concatenate(depths), {k: np.concatenate(v) for k, v in maps.items()})


def stamp_spec(path: Path, out: Path) -> ModelSpec:
    """Copy someone else's model to ``out`` with its side-car spec inside, as vista's
    metadata (what a `model` artifact needs)."""
    import onnx

    from services.lib.nn.onnx_io import METADATA_KEY

    spec = read_spec(path)
    proto = onnx.load_model(str(path))
    kept = [p for p in proto.metadata_props if p.key != METADATA_KEY]
    del proto.metadata_props[:]
    proto.metadata_props.extend(kept)
    entry = proto.metadata_props.add()
    metadata = {"service": "depth", "architecture": f"imported {path.name}", **spec.metadata}
    entry.key, entry.value = METADATA_KEY, json.dumps(metadata, sort_keys=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(proto, str(out))
    return read_spec(out)
