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
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

METADATA_KEY = "vista"
STORED_INT8 = "_stored_int8"
"""The name's end of the nodes that dequantise weights stored in int8 (``store_weights_int8``);
an int8 model's own quantisation nodes are left to onnxruntime."""
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
    """An onnxruntime session on ``threads`` threads that sleep instead of spinning; a model
    whose weights are stored in int8 (``store_weights_int8``) gets them in float once, here
    (onnxruntime would dequantise them on every run: twice the time)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.add_session_config_entry("session.inter_op.allow_spinning", "0")
    model = _weights_in_float(Path(path)) or str(path)
    return ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])


def _weights_in_float(path: Path) -> bytes | None:
    """The model with its int8-stored weights dequantised (serialised), or None when it
    stores none: the ``DequantizeLinear`` nodes ``store_weights_int8`` added."""
    import onnx
    from onnx import numpy_helper

    proto = onnx.load_model(str(path))
    stored = {i.name: i for i in proto.graph.initializer}
    constant = [
        node
        for node in proto.graph.node
        if node.op_type == "DequantizeLinear"
        and node.name.endswith(STORED_INT8)
        and all(name in stored for name in node.input)
    ]
    if not constant:
        return None
    for node in constant:
        quantized, scale, *zero = (numpy_helper.to_array(stored[n]) for n in node.input)
        axis = next((a.i for a in node.attribute if a.name == "axis"), 1)
        shape = [1] * quantized.ndim
        if scale.ndim:
            shape[axis] = len(scale)
        offset = zero[0].astype(np.float32).reshape(shape) if zero else 0.0
        weight = (quantized.astype(np.float32) - offset) * scale.reshape(shape)
        proto.graph.initializer.append(numpy_helper.from_array(weight, node.output[0]))
        proto.graph.node.remove(node)
    used = {name for node in proto.graph.node for name in node.input}
    keep = [i for i in proto.graph.initializer if i.name in used]
    del proto.graph.initializer[:]
    proto.graph.initializer.extend(keep)
    return proto.SerializeToString()


def read_model(path: Path) -> ModelFile:
    """A model file's metadata; ValueError when it is not an ONNX file of vista's."""
    import onnx

    try:
        proto = onnx.load_model(str(path), load_external_data=False)
    except Exception as exc:  # onnx raises several types for a bad file
        raise ValueError(f"{path}: not an ONNX model ({type(exc).__name__})") from None
    for entry in proto.metadata_props:
        if entry.key == METADATA_KEY:
            return ModelFile(path, _metadata(path, entry.value))
    raise ValueError(f"{path}: an ONNX model without vista's metadata (not built by vista)")


def _metadata(path: Path, text: str | bytes) -> dict:
    """vista's metadata document (protobuf hands a string that is not UTF-8 over as bytes)."""
    from services.lib.archive import parse_json

    try:
        metadata = parse_json(text if isinstance(text, bytes) else text.encode("utf-8"))
    except ValueError as exc:
        raise ValueError(f"{path}: its metadata '{METADATA_KEY}' is not JSON ({exc})") from None
    if not isinstance(metadata, dict):
        raise ValueError(f"{path}: its metadata '{METADATA_KEY}' is not a JSON object")
    return metadata


def _tensors(graph) -> Iterator:  # noqa: ANN001 - an onnx.GraphProto
    """Every tensor stored in ``graph`` and its subgraphs (an ``If``'s branches, a ``Loop``'s
    body): initializers, sparse ones and the constants held in node attributes."""
    graphs = [graph]
    while graphs:
        current = graphs.pop()
        yield from current.initializer
        for sparse in current.sparse_initializer:
            yield from (sparse.values, sparse.indices)
        for node in current.node:
            for attribute in node.attribute:
                if attribute.HasField("t"):
                    yield attribute.t
                yield from attribute.tensors
                if attribute.HasField("g"):
                    graphs.append(attribute.g)
                graphs.extend(attribute.graphs)


def check_runnable(path: Path) -> None:
    """ValueError saying why onnxruntime could not run the model in ``path``: weights in
    external files (an upload is one file, and a path inside the model must never reach the
    server's disk), or what creating a CPU session says (an operator of a domain onnxruntime
    lacks, a graph it cannot load). The session is built from the bytes, never the path."""
    import onnx
    import onnxruntime as ort

    data = Path(path).read_bytes()
    try:
        proto = onnx.load_model_from_string(data)
    except Exception as exc:  # onnx raises several types for a bad file
        raise ValueError(f"{path}: not an ONNX model ({type(exc).__name__})") from None
    external = next(
        (t.name for t in _tensors(proto.graph) if t.data_location == onnx.TensorProto.EXTERNAL),
        None,
    )
    if external is not None:
        raise ValueError(
            f"{path}: tensor {external[:60]!r} keeps its data in an external file; save the "
            "model with its weights inside (onnx.save_model(..., save_as_external_data=False))"
        )
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.log_severity_level = 4  # the reason is raised, not logged
    # every node still needs a kernel; no optimisation pass runs over an untrusted graph
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    try:
        ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime's own exception types, one per status code
        raise ValueError(f"{path}: onnxruntime cannot run it ({_ort_reason(exc)})") from None


def _ort_reason(exc: Exception) -> str:
    """onnxruntime's message without its status prefix and load-path boilerplate, short."""
    text = " ".join(str(exc).split())
    text = re.sub(r"^\[ONNXRuntimeError\] : \d+ : \w+ : ", "", text)
    text = re.sub(r"^Load model from .*? failed:\s*", "", text)
    return text[:200] + ("…" if len(text) > 200 else "")


def fold_batch_norms(module):  # noqa: ANN001, ANN201 - a torch.nn.Module, changed in place
    """Each convolution followed by a batch norm — in a ``Sequential``, or as a module's
    ``convK``/``bnK`` pair (ResNet's blocks) — becomes one convolution with a bias (the batch
    norm an identity): the network as its ONNX export computes it, which
    ``load_onnx_weights`` can fill and a fine-tuning run can train without batch statistics
    (a few scans or frames make poor ones)."""
    from torch import nn
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    convolutions = nn.Conv2d | nn.ConvTranspose2d | nn.Conv1d
    norms = nn.BatchNorm2d | nn.BatchNorm1d

    def fused(conv, norm):  # noqa: ANN001, ANN202 - torch modules
        return fuse_conv_bn_eval(
            conv.eval(), norm.eval(), transpose=isinstance(conv, nn.ConvTranspose2d)
        )

    for parent in list(module.modules()):
        if isinstance(parent, nn.Sequential):
            for index in range(len(parent) - 1):
                conv, norm = parent[index], parent[index + 1]
                if isinstance(conv, convolutions) and isinstance(norm, norms):
                    parent[index] = fused(conv, norm)
                    parent[index + 1] = nn.Identity()
            continue
        children = dict(parent.named_children())
        for name, norm in children.items():
            conv = children.get("conv" + name.removeprefix("bn"))
            if name.startswith("bn") and isinstance(norm, norms) and isinstance(conv, convolutions):
                setattr(parent, "conv" + name.removeprefix("bn"), fused(conv, norm))
                setattr(parent, name, nn.Identity())
    return module


def load_onnx_weights(module, path: Path, *, unused: tuple[str, ...] = ()) -> None:  # noqa: ANN001 - a torch.nn.Module
    """Fill ``module`` (batch norms folded, ``fold_batch_norms``) with the weights of the
    ONNX file it was exported to: each layer's weight and bias by the layer's name;
    ValueError when the file does not fit the network. Layers named in ``unused`` (prefixes:
    the training-only heads an export drops) may be absent and keep their weights."""
    import onnx
    import torch
    from onnx import numpy_helper
    from torch import nn

    proto = onnx.load_model(str(path))
    stored = {i.name: numpy_helper.to_array(i) for i in proto.graph.initializer}
    # a folded convolution's bias is named by the exporter: take it from the node's inputs
    bias_of = {
        node.input[1]: node.input[2]
        for node in proto.graph.node
        if node.op_type in ("Conv", "ConvTranspose", "Gemm") and len(node.input) > 2
    }
    for name, layer in module.named_modules():
        if not isinstance(layer, nn.Conv2d | nn.ConvTranspose2d | nn.Conv1d | nn.Linear):
            continue
        # a model exported inside a wrapper (a teacher with its features) has its prefix
        key = next(
            (k for k in (f"{name}.weight", f"inner.{name}.weight") if k in stored),
            f"{name}.weight",
        )
        weight = stored.get(key)
        if weight is None and name.startswith(unused):
            continue
        bias = stored.get(bias_of.get(key, ""), stored.get(key.removesuffix("weight") + "bias"))
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


def store_weights_int8(path: Path, out: Path, *, min_elements: int = 1024) -> Path:
    """Write ``path``'s model to ``out`` with each large weight (a float initializer of two or
    more dimensions and at least ``min_elements`` values) stored in int8, one symmetric scale
    per output channel, behind a ``DequantizeLinear``: a quarter of the size, computed in
    float as before (the per-channel rounding is at most half a step, 1/254 of the channel's
    largest weight). The metadata is kept."""
    import onnx
    from onnx import helper, numpy_helper

    proto = onnx.load_model(str(path))
    kept, nodes = [], []
    for initializer in proto.graph.initializer:
        weight = numpy_helper.to_array(initializer)
        if weight.dtype != np.float32 or weight.ndim < 2 or weight.size < min_elements:
            kept.append(initializer)
            continue
        name = initializer.name
        largest = np.abs(weight.reshape(len(weight), -1)).max(axis=1)
        scale = np.where(largest > 0, largest / 127, 1.0).astype(np.float32)
        shaped = scale.reshape((-1,) + (1,) * (weight.ndim - 1))
        quantized = np.clip(np.rint(weight / shaped), -127, 127).astype(np.int8)
        kept += [
            numpy_helper.from_array(quantized, f"{name}_int8"),
            numpy_helper.from_array(scale, f"{name}_scale"),
            numpy_helper.from_array(np.zeros(len(scale), np.int8), f"{name}_zero"),
        ]
        nodes.append(
            helper.make_node(
                "DequantizeLinear",
                [f"{name}_int8", f"{name}_scale", f"{name}_zero"],
                [name],
                axis=0,
                name=f"{name}{STORED_INT8}",
            )
        )
    del proto.graph.initializer[:]
    proto.graph.initializer.extend(kept)
    graph_nodes = list(proto.graph.node)
    del proto.graph.node[:]
    proto.graph.node.extend(nodes + graph_nodes)
    onnx.checker.check_model(proto)
    out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(proto, str(out))
    return out
