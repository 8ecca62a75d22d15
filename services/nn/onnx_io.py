"""Models as ONNX files with their metadata, checked against torch when exported, and
onnxruntime sessions that do not spin.

The metadata (``metadata_props`` of the ONNX model) says what a model is: its
architecture, the data it was trained on, its input (name, shape, dtype, units), what it
outputs and its measured metrics — a JSON object under the key ``vista``.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

METADATA_KEY = "vista"
TOLERANCE = 1e-4
"""Largest difference allowed between onnxruntime's output and torch's (relative to the
output's scale)."""


@dataclass(frozen=True)
class ModelFile:
    path: Path
    metadata: dict


def export_onnx(
    model,  # noqa: ANN001 - a torch.nn.Module in eval mode
    example: np.ndarray,
    path: Path,
    metadata: dict,
    *,
    input_name: str = "input",
    output_name: str | tuple[str, ...] = "output",
    free_axes: tuple[int, ...] = (0,),
) -> float:
    """Write ``model`` to ``path`` (the input's ``free_axes`` free: the batch by default;
    a fully convolutional network may free its image's height and width) with
    ``metadata``; run the file in onnxruntime on ``example`` and return the largest
    difference from torch's output (ValueError when it exceeds ``TOLERANCE`` of the output's
    scale). A model answering a tuple gets one name per output in ``output_name``, each
    checked."""
    import onnx
    import torch

    names = (output_name,) if isinstance(output_name, str) else tuple(output_name)
    model.eval()
    tensor = torch.from_numpy(np.ascontiguousarray(example, dtype=np.float32))
    with torch.no_grad():
        answer = model(tensor)
    expected = [t.numpy() for t in (answer if isinstance(answer, tuple) else (answer,))]
    if len(expected) != len(names):
        raise ValueError(f"the model answers {len(expected)} outputs, named {names}")
    # the exporter narrates on stdout and warns about torchvision, which vista does not use
    quiet = logging.getLogger("torch.onnx")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(
                model,
                (tensor,),
                input_names=[input_name],
                output_names=list(names),
                dynamic_shapes=({axis: torch.export.Dim(f"axis{axis}") for axis in free_axes},),
                dynamo=True,
                verbose=False,
            )
    finally:
        quiet.setLevel(level)
    proto = program.model_proto
    entry = proto.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, json.dumps(metadata, sort_keys=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(proto, str(path))
    got = session(path, threads=1).run(None, {input_name: example.astype(np.float32)})
    worst = 0.0
    for name, mine, theirs in zip(names, got, expected, strict=True):
        difference = float(np.abs(mine - theirs).max())
        scale = float(np.abs(theirs).max()) or 1.0
        if difference > TOLERANCE * max(scale, 1.0):
            raise ValueError(
                f"{path}: onnxruntime's {name!r} differs from torch's by {difference:.2e} "
                f"(scale {scale:.2e})"
            )
        worst = max(worst, difference)
    return worst


def session(path: Path, threads: int = 1):  # noqa: ANN201 - an onnxruntime.InferenceSession
    """An onnxruntime session on ``threads`` threads that sleep instead of spinning."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.add_session_config_entry("session.inter_op.allow_spinning", "0")
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def read_model(path: Path) -> ModelFile:
    """A model file's metadata; ValueError when it is not an ONNX file of vista's."""
    import onnx

    try:
        proto = onnx.load_model(str(path), load_external_data=False)
    except Exception as exc:  # onnx raises several types for a bad file
        raise ValueError(f"{path}: not an ONNX model ({type(exc).__name__})") from None
    for entry in proto.metadata_props:
        if entry.key == METADATA_KEY:
            return ModelFile(path, json.loads(entry.value))
    raise ValueError(f"{path}: an ONNX model without vista's metadata (not built by vista)")


def fold_batch_norms(module):  # noqa: ANN001, ANN201 - a torch.nn.Module, changed in place
    """Each convolution followed by a batch norm in a ``Sequential`` becomes one convolution
    with a bias (the batch norm an identity): the network as its ONNX export computes it,
    which ``load_onnx_weights`` can fill and a fine-tuning run can train without batch
    statistics (a few scans make poor ones)."""
    from torch import nn
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    for sequential in [m for m in module.modules() if isinstance(m, nn.Sequential)]:
        for index in range(len(sequential) - 1):
            conv, norm = sequential[index], sequential[index + 1]
            if isinstance(conv, nn.Conv2d | nn.ConvTranspose2d | nn.Conv1d) and isinstance(
                norm, nn.BatchNorm2d | nn.BatchNorm1d
            ):
                sequential[index] = fuse_conv_bn_eval(
                    conv.eval(), norm.eval(), transpose=isinstance(conv, nn.ConvTranspose2d)
                )
                sequential[index + 1] = nn.Identity()
    return module


def load_onnx_weights(module, path: Path) -> None:  # noqa: ANN001 - a torch.nn.Module
    """Fill ``module`` (batch norms folded, ``fold_batch_norms``) with the weights of the
    ONNX file it was exported to: each layer's weight and bias by the layer's name;
    ValueError when the file does not fit the network."""
    import onnx
    import torch
    from onnx import numpy_helper
    from torch import nn

    proto = onnx.load_model(str(path))
    stored = {i.name: numpy_helper.to_array(i) for i in proto.graph.initializer}
    for name, layer in module.named_modules():
        if not isinstance(layer, nn.Conv2d | nn.ConvTranspose2d | nn.Conv1d | nn.Linear):
            continue
        weight = stored.get(f"{name}.weight")
        bias = stored.get(f"{name}.bias", stored.get(f"{name}.weight_bias"))
        if weight is None or weight.shape != tuple(layer.weight.shape):
            raise ValueError(f"{path}: no weights of the shape of layer {name!r}: another network")
        with torch.no_grad():
            layer.weight.copy_(torch.from_numpy(weight.copy()))
            if layer.bias is not None:
                layer.bias.copy_(
                    torch.from_numpy(bias.copy())
                    if bias is not None
                    else torch.zeros_like(layer.bias)
                )
