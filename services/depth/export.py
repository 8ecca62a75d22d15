"""Depth networks to ONNX files that carry their spec (``models.ModelSpec``) in vista's
metadata: RGB in 0–1, NCHW, at a fixed size; depth in metres out (and, for a teacher, its
``encoder`` and ``decoder`` features, which vista's distillation learns from)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.depth.nets import MAX_DEPTH_M, MIN_DEPTH_M, parameters


def depth_metadata(architecture: str, width: int, height: int, count: int, extra: dict) -> dict:
    return {
        "service": "depth",
        "architecture": architecture,
        "parameters": count,
        "input": {
            "width": width,
            "height": height,
            "range": 1.0,
            "mean": [0.0, 0.0, 0.0],
            "std": [1.0, 1.0, 1.0],
            "channels": "RGB",
            "layout": "NCHW",
        },
        "output": {
            "kind": "depth",
            "scale": 1.0,
            "unit": "m",
            "min_depth_m": MIN_DEPTH_M,
            "max_depth_m": MAX_DEPTH_M,
        },
        **extra,
    }


def export_depth_model(
    model,  # noqa: ANN001 - nets.Student or nets.Teacher
    path: Path,
    *,
    width: int,
    height: int,
    architecture: str,
    features: bool = False,
    extra: dict | None = None,
    example: np.ndarray | None = None,
) -> float:
    """Write ``model`` at (width, height) to ``path``; the largest difference between
    onnxruntime and torch on ``example`` (a random image if none) is checked and returned."""
    import torch

    from services.lib.nn.onnx_io import export_onnx

    class WithFeatures(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.inner = model

        def forward(self, rgb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            out = self.inner.forward_train(rgb)
            return out["depth"], out["encoder"], out["decoder"]

    if example is None:
        example = np.random.default_rng(0).random((1, 3, height, width), dtype=np.float32)
    metadata = depth_metadata(architecture, width, height, parameters(model), extra or {})
    names: tuple[str, ...] = ("depth", "encoder", "decoder") if features else ("depth",)
    model.eval()
    return export_onnx(
        WithFeatures() if features else model,
        example,
        path,
        metadata,
        input_name="rgb",
        output_name=names,
    )
