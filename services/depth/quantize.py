"""int8 models: onnxruntime's static quantization (per-channel int8 weights, int8
activations; QDQ by default, or the QOperator format's fused int8 operators), calibrated on
the user's own images, the spec carried over."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from services.depth.models import DepthModel
from services.lib.nn.onnx_io import METADATA_KEY

CALIBRATION_IMAGES = 32


def quantize_int8(
    model: DepthModel, images: np.ndarray, out: Path, *, operators: bool = False
) -> Path:
    """Write ``model`` quantized to int8 at ``out``, its activation ranges calibrated on
    ``images`` ((N, H, W, 3) uint8 at the model's size, up to ``CALIBRATION_IMAGES``);
    ``operators``: the QOperator format (QLinearConv …) instead of QDQ."""
    import onnx
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if len(images) == 0:
        raise ValueError("int8 calibration needs at least one image")
    chosen = images[
        np.linspace(0, len(images) - 1, min(len(images), CALIBRATION_IMAGES)).astype(int)
    ]

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.items = iter([{model.input_name: model.prepare(image[None])} for image in chosen])

        def get_next(self) -> dict | None:
            return next(self.items, None)

    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as work:
        prepared = Path(work) / "prepared.onnx"
        quant_pre_process(str(model.path), str(prepared), skip_symbolic_shape=True)
        quantize_static(
            str(prepared),
            str(out),
            Reader(),
            quant_format=QuantFormat.QOperator if operators else QuantFormat.QDQ,
            per_channel=True,
            weight_type=QuantType.QInt8,
            # QOperator's int8 kernels on x64 want unsigned activations (onnxruntime's advice)
            activation_type=QuantType.QUInt8 if operators else QuantType.QInt8,
            extra_options={"ActivationSymmetric": False, "WeightSymmetric": True},
        )
    proto = onnx.load_model(str(out))
    del proto.metadata_props[:]
    entry = proto.metadata_props.add()
    entry.key = METADATA_KEY
    entry.value = json.dumps(
        {
            **model.spec.metadata,
            "quantization": {
                "kind": f"int8 static {'QOperator' if operators else 'QDQ'}",
                "calibration_images": len(chosen),
            },
        },
        sort_keys=True,
    )
    onnx.save_model(proto, str(out))
    return out
