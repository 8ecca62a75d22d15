"""A binary glTF 2.0 (GLB) writer for inspection and job scenes: points, triangle meshes,
lines, marker and anchor nodes, node animations. Pure: arrays and dicts in, bytes out.

Everything given here is already in glTF's frame (metres, +Y up); ``base_to_gltf`` and
``pose_to_gltf`` convert from vista's base frame (millimetres, +Z up).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
FLOAT, UNSIGNED_BYTE, UNSIGNED_INT = 5126, 5121, 5125
POINTS, LINE_LOOP, LINE_STRIP, TRIANGLES = 0, 2, 3, 4
LINE_MODES = {"loop": LINE_LOOP, "strip": LINE_STRIP}

GLTF_R_BASE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Rotation of vista's Z-up base frame into glTF's Y-up frame: (x, y, z) → (x, z, −y)."""
MM_TO_M = 1e-3
GLTF_T_BASE = np.block([[GLTF_R_BASE * MM_TO_M, np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]])
"""The whole conversion as one 4 × 4 matrix (points in mm → points in m)."""


def base_to_gltf(points_mm: np.ndarray, dtype: type = np.float32) -> np.ndarray:
    """(N, 3) base-frame points, mm → (N, 3) glTF points, m (float32 for vertex data,
    float64 for node positions)."""
    return (np.asarray(points_mm, dtype=np.float64) @ (GLTF_R_BASE.T * MM_TO_M)).astype(dtype)


def quaternion_xyzw(rotation: np.ndarray) -> list[float]:
    """The unit quaternion (x, y, z, w) of a 3 × 3 rotation matrix (Shepperd's method)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = np.trace(m)
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
    q = np.array(q) / np.linalg.norm(q)
    return [float(c) for c in (q if q[3] >= 0 else -q)]


def pose_to_gltf(base_T_frame: np.ndarray) -> tuple[list[float], list[float]]:
    """A base-frame pose (4 × 4, mm) → glTF (translation m, rotation quaternion xyzw)."""
    pose = np.asarray(base_T_frame, dtype=np.float64)
    rotation = GLTF_R_BASE @ pose[:3, :3] @ GLTF_R_BASE.T
    translation = GLTF_R_BASE @ pose[:3, 3] * MM_TO_M
    return [float(c) for c in translation], quaternion_xyzw(rotation)


@dataclass(frozen=True)
class Material:
    name: str
    rgba: tuple[float, float, float, float]
    double_sided: bool = False


@dataclass(frozen=True)
class Mesh:
    """Triangles (``indices`` (M, 3)), points (``indices`` None) or, with ``lines``, a
    line through the positions in order (``loop``: closed, ``strip``: open); in glTF
    metres."""

    name: str
    positions: np.ndarray
    """(N, 3) float32, m."""
    colors: np.ndarray | None = None
    """(N, 4) uint8 RGBA, or None."""
    normals: np.ndarray | None = None
    """(N, 3) float32 unit vectors, or None."""
    indices: np.ndarray | None = None
    material: int | None = None
    lines: Literal["loop", "strip"] | None = None


@dataclass(frozen=True)
class Channel:
    """One animated property of one node: its values at the key times."""

    node: int
    path: Literal["translation", "rotation", "scale"]
    times_s: np.ndarray
    """(K,) increasing."""
    values: np.ndarray
    """(K, 3) translations or scales, (K, 4) rotations (x, y, z, w)."""
    interpolation: Literal["LINEAR", "STEP"] = "LINEAR"


@dataclass(frozen=True)
class Animation:
    name: str
    channels: list[Channel]


@dataclass(frozen=True)
class Node:
    name: str
    mesh: int | None = None
    translation: list[float] | None = None
    rotation: list[float] | None = None
    scale: list[float] | None = None
    children: list[int] = field(default_factory=list)
    extras: dict | None = None


class _Buffer:
    """The binary chunk: views appended 4-byte aligned."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.length = 0
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(
        self, array: np.ndarray, *, target: int | None, component: int, kind: str, **extra
    ) -> int:
        """An accessor of ``array``; ``target`` None for animation data (no GPU buffer)."""
        data = np.ascontiguousarray(array).tobytes()
        view = {"buffer": 0, "byteOffset": self.length, "byteLength": len(data)}
        self.views.append(view if target is None else {**view, "target": target})
        padding = -len(data) % 4
        self.parts += [data, b"\0" * padding]
        self.length += len(data) + padding
        self.accessors.append(
            {
                "bufferView": len(self.views) - 1,
                "componentType": component,
                "count": int(len(array)),
                "type": kind,
                **extra,
            }
        )
        return len(self.accessors) - 1


def _primitive(buffer: _Buffer, mesh: Mesh) -> dict:
    positions = np.asarray(mesh.positions, dtype=np.float32)
    if positions.ndim != 2 or positions.shape[1] != 3 or not len(positions):
        raise ValueError(f"mesh {mesh.name}: positions must be a non-empty (N, 3) array")
    attributes = {
        "POSITION": buffer.add(
            positions,
            target=ARRAY_BUFFER,
            component=FLOAT,
            kind="VEC3",
            min=[float(c) for c in positions.min(axis=0)],
            max=[float(c) for c in positions.max(axis=0)],
        )
    }
    if mesh.normals is not None:
        attributes["NORMAL"] = buffer.add(
            np.asarray(mesh.normals, dtype=np.float32),
            target=ARRAY_BUFFER,
            component=FLOAT,
            kind="VEC3",
        )
    if mesh.colors is not None:
        attributes["COLOR_0"] = buffer.add(
            np.asarray(mesh.colors, dtype=np.uint8),
            target=ARRAY_BUFFER,
            component=UNSIGNED_BYTE,
            kind="VEC4",
            normalized=True,
        )
    primitive: dict = {"attributes": attributes, "mode": LINE_MODES.get(mesh.lines, POINTS)}
    if mesh.indices is not None:
        indices = np.asarray(mesh.indices, dtype=np.uint32).reshape(-1)
        primitive["indices"] = buffer.add(
            indices, target=ELEMENT_ARRAY_BUFFER, component=UNSIGNED_INT, kind="SCALAR"
        )
        primitive["mode"] = TRIANGLES
    if mesh.material is not None:
        primitive["material"] = mesh.material
    return primitive


def _animation(buffer: _Buffer, animation: Animation) -> dict:
    samplers, channels = [], []
    for channel in animation.channels:
        times = np.asarray(channel.times_s, dtype=np.float32)
        values = np.asarray(channel.values, dtype=np.float32)
        if times.ndim != 1 or len(times) != len(values) or np.any(np.diff(times) <= 0):
            raise ValueError(f"animation {animation.name}: key times must increase, one a value")
        key_times = buffer.add(
            times,
            target=None,
            component=FLOAT,
            kind="SCALAR",
            min=[float(times.min())],
            max=[float(times.max())],
        )
        output = buffer.add(
            values, target=None, component=FLOAT, kind="VEC4" if values.shape[1] == 4 else "VEC3"
        )
        samplers.append(
            {"input": key_times, "output": output, "interpolation": channel.interpolation}
        )
        channels.append(
            {"sampler": len(samplers) - 1, "target": {"node": channel.node, "path": channel.path}}
        )
    return {"name": animation.name, "samplers": samplers, "channels": channels}


def _node_json(node: Node) -> dict:
    out: dict = {"name": node.name}
    for key in ("mesh", "translation", "rotation", "scale", "extras"):
        value = getattr(node, key)
        if value is not None:
            out[key] = value
    if node.children:
        out["children"] = node.children
    return out


def write_glb(
    *,
    meshes: list[Mesh],
    materials: list[Material],
    nodes: list[Node],
    roots: list[int],
    asset_extras: dict,
    animations: list[Animation] = (),
    scene_name: str = "inspection",
) -> bytes:
    """The GLB file of one scene whose top-level nodes are ``roots``."""
    buffer = _Buffer()
    meshes_json = [{"name": m.name, "primitives": [_primitive(buffer, m)]} for m in meshes]
    animations_json = [_animation(buffer, a) for a in animations]
    document = {
        "asset": {"version": "2.0", "generator": "vista supervisor", "extras": asset_extras},
        "scene": 0,
        "scenes": [{"name": scene_name, "nodes": roots}],
        "nodes": [_node_json(n) for n in nodes],
        "meshes": meshes_json,
        "materials": [
            {
                "name": m.name,
                "pbrMetallicRoughness": {
                    "baseColorFactor": list(m.rgba),
                    "metallicFactor": 0.0,
                    "roughnessFactor": 0.8,
                },
                **({"doubleSided": True} if m.double_sided else {}),
                **({"alphaMode": "BLEND"} if m.rgba[3] < 1 else {}),
            }
            for m in materials
        ],
        "accessors": buffer.accessors,
        "bufferViews": buffer.views,
        "buffers": [{"byteLength": buffer.length}],
        "animations": animations_json,
    }
    if not buffer.length:
        del document["buffers"]
    for key in ("meshes", "materials", "accessors", "bufferViews", "animations"):
        if not document[key]:
            del document[key]  # glTF forbids empty arrays
    payload = json.dumps(document, separators=(",", ":")).encode()
    payload += b" " * (-len(payload) % 4)
    binary = b"".join(buffer.parts)
    chunks = struct.pack("<II", len(payload), 0x4E4F534A) + payload
    if binary:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks


def ring(segments: int = 48, inner: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """A flat unit ring (outer radius 1, ``inner`` radius) in the XZ plane, facing +Y:
    (2·segments, 3) float32 vertices and (2·segments, 3) uint32 faces. A marker drawn
    with it circles what it marks instead of covering it."""
    angle = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    circle = np.column_stack([np.cos(angle), np.zeros(segments), -np.sin(angle)])
    vertices = np.concatenate([circle, inner * circle]).astype(np.float32)
    outer = np.arange(segments)
    following = (outer + 1) % segments
    faces = np.concatenate(
        [
            np.column_stack([outer, following, outer + segments]),
            np.column_stack([following, following + segments, outer + segments]),
        ]
    )
    return vertices, faces.astype(np.uint32)


def rotation_from_y(direction: np.ndarray) -> list[float]:
    """The quaternion (x, y, z, w) turning +Y onto ``direction`` (glTF frame)."""
    y = np.asarray(direction, dtype=np.float64)
    if not np.linalg.norm(y) > 1e-9:
        return [0.0, 0.0, 0.0, 1.0]
    y = y / np.linalg.norm(y)
    helper = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(y, helper)
    x /= np.linalg.norm(x)
    return quaternion_xyzw(np.column_stack([x, y, np.cross(x, y)]))
