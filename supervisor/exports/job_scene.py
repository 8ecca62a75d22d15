"""A job's results in 3D as binary glTF 2.0: what its kind's ``scene`` hook returns
(``contract.scene.JobScene``), in metres with +Y up. Built once per job and point budget
(a finished job's files do not change) and cached beside the inspection's scenes — the
newest budget only, so that asking for many budgets cannot fill the disk.

Node layout (names are stable; clients find things by them)::

    job-<id>                  extras: the job's kind, the run's figures, the frame
    ├── <group>/<line>        line groups (a trajectory: ``path``, with σ in extras)
    ├── <points>              POINTS with COLOR_0; a drive's scans ``scan-<frame>``, each
    │                         shown for its frame by a STEP animation of its scale
    └── <box>                 a wire box, its pose animated one key a frame (a box of one
                              frame, a detection, shown for it as a scan is)
"""

from __future__ import annotations

import hashlib
from typing import BinaryIO

import numpy as np

from contract.scene import JobScene, MovingBox, PointSet
from supervisor.engine.registry import get_kind
from supervisor.engine.runtime import Runtime
from supervisor.exports.cache import open_cached, publish, remove_others
from supervisor.exports.gltf import (
    Animation,
    Channel,
    Material,
    Mesh,
    Node,
    base_to_gltf,
    pose_to_gltf,
    write_glb,
)
from supervisor.exports.scene import add_line_groups
from supervisor.jobs.service import get_job
from supervisor.jobs.view import job_files
from supervisor.problems import Problem

# a unit cube's twelve edges as one line strip (some edges drawn twice), centred at 0
_CORNERS = np.array(
    [[x, y, z] for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)], np.float32
)
WIRE_BOX = _CORNERS[[0, 1, 3, 2, 0, 4, 5, 1, 5, 7, 3, 7, 6, 2, 6, 4]]
"""(16, 3) in the box's own frame (x along its length, y its width, z its height)."""


def job_scene_file(runtime: Runtime, job_id: int, max_points: int) -> BinaryIO:
    """The cached GLB of job ``job_id``'s scene at ``max_points``, built if missing, open
    for reading; a problem (404, 409) when the job has none."""
    with runtime.db.read() as session:
        job = get_job(session, job_id=job_id)
        kind = get_kind(job.kind)
        hook = kind.shows.load_scene() if kind is not None else None
        if hook is None:
            raise Problem(404, f"Job {job_id} ({job.kind}) has no 3D scene.")
        if job.status != "succeeded":
            raise Problem(
                409, f"Job {job_id} has not succeeded (it is {job.status}): no scene yet."
            )
        key = f"{job.id}:{job.finished_at}:{max_points}"
        folder = runtime.storage.export_dir(job.inspection_id)
        path = folder / f"job-{job.id}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.glb"
        if (cached := open_cached(path)) is not None:
            return cached
        files = job_files(session, runtime.storage, job)[2]
        about = {"job_id": job.id, "kind": job.kind, "step": job.step}
    try:
        scene = hook(files, max_points)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise Problem(409, f"Job {job_id}'s results could not be drawn: {exc}") from exc
    handle = publish(path, job_scene_glb(scene, about))
    remove_others(folder, f"job-{job_id}-*.glb", path)  # one budget a job: no disk to fill
    return handle


def job_scene_glb(scene: JobScene, about: dict) -> bytes:
    """The GLB of ``scene`` (see the module docstring for its layout)."""
    meshes: list[Mesh] = []
    materials: list[Material] = []
    root = Node(f"job-{about['job_id']}", children=[], extras={**about, **scene.extras})
    nodes: list[Node] = [root]
    channels: list[Channel] = []
    add_line_groups(scene.lines, meshes, materials, nodes, root.children)
    for surface in scene.surfaces:
        materials.append(Material(surface.name, surface.colour_rgba, double_sided=True))
        meshes.append(
            Mesh(
                surface.name,
                base_to_gltf(np.asarray(surface.vertices_mm, np.float64)),
                indices=np.asarray(surface.faces, np.uint32),
                material=len(materials) - 1,
            )
        )
        root.children.append(len(nodes))
        nodes.append(Node(surface.name, mesh=len(meshes) - 1, extras=surface.extras))
    for points in scene.points:
        _add_points(points, scene.frame_s, meshes, nodes, root.children, channels)
    wire_boxes: dict[tuple, int] = {}  # a box's colour → the wire box mesh boxes of it share
    for box in scene.boxes:
        if box.colour_rgba not in wire_boxes:
            name = f"wire-box-{len(wire_boxes)}"
            materials.append(Material(name, box.colour_rgba))
            # the unit wire box in glTF's axes (its height along +Y), sized by its nodes
            meshes.append(
                Mesh(
                    name,
                    base_to_gltf(WIRE_BOX * 1000.0),
                    material=len(materials) - 1,
                    lines="strip",
                )
            )
            wire_boxes[box.colour_rgba] = len(meshes) - 1
        _add_box(box, wire_boxes[box.colour_rgba], scene.frame_s, nodes, root.children, channels)
    extras = {
        "units": "metre",
        "up": "+Y",
        "converted_from": f"{scene.frame or 'the job frame'}: millimetres, +Z up",
        "frame_s": scene.frame_s,
        **about,
    }
    animations = [Animation("frames", channels)] if channels else []
    return write_glb(
        meshes=meshes,
        materials=materials,
        nodes=nodes,
        roots=[0],
        asset_extras=extras,
        animations=animations,
        scene_name=f"job-{about['job_id']}",
    )


def _add_points(
    points: PointSet,
    frame_s: float,
    meshes: list[Mesh],
    nodes: list[Node],
    children: list[int],
    channels: list[Channel],
) -> None:
    if not len(points.points_mm):
        return
    colours = None
    if points.colours_rgb is not None:
        rgb = np.asarray(points.colours_rgb, np.uint8)
        colours = np.column_stack([rgb, np.full(len(rgb), 255, np.uint8)])
    meshes.append(Mesh(points.name, base_to_gltf(points.points_mm), colors=colours))
    scale = None if points.shown_at_s is None or points.shown_at_s <= 0 else [0.0, 0.0, 0.0]
    children.append(len(nodes))
    nodes.append(Node(points.name, mesh=len(meshes) - 1, scale=scale, extras=points.extras))
    _show_for_frame(len(nodes) - 1, np.ones(3), points.shown_at_s, frame_s, channels)


def _show_for_frame(
    node: int, scale: np.ndarray, shown_at_s: float | None, frame_s: float, channels: list[Channel]
) -> None:
    """A node of one frame (``shown_at_s``; None: of every frame) scaled to nothing out of it
    by a STEP animation of its scale."""
    if shown_at_s is None:
        return
    off = np.zeros(3)
    if shown_at_s <= 0:
        times, values = [0.0, frame_s], [scale, off]
    else:
        times, values = [0.0, shown_at_s, shown_at_s + frame_s], [off, scale, off]
    channels.append(Channel(node, "scale", np.array(times), np.array(values), "STEP"))


def _add_box(
    box: MovingBox,
    mesh: int,
    frame_s: float,
    nodes: list[Node],
    children: list[int],
    channels: list[Channel],
) -> None:
    poses = np.tile(np.eye(4), (len(box.times_s), 1, 1))
    c, s = np.cos(box.yaw_rad), np.sin(box.yaw_rad)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = c, -s, s, c
    poses[:, :3, 3] = box.centres_mm
    keyed = [pose_to_gltf(p) for p in poses]
    quaternions = np.array([k[1] for k in keyed])
    # one sign for neighbouring keys, so that each step turns the short way
    flips = np.cumprod(np.where(np.sum(quaternions[1:] * quaternions[:-1], axis=1) < 0, -1, 1))
    quaternions[1:] *= flips[:, None]
    length, width, height = (v / 1000 for v in box.size_mm)
    translation, rotation = keyed[0]
    size = [length, height, width]
    hidden = box.shown_at_s is not None and box.shown_at_s > 0
    children.append(len(nodes))
    nodes.append(
        Node(
            box.name,
            mesh=mesh,
            translation=translation,
            rotation=rotation,
            scale=[0.0, 0.0, 0.0] if hidden else size,
            extras={"size_m": [length, width, height], **box.extras},
        )
    )
    node = len(nodes) - 1
    _show_for_frame(node, np.array(size), box.shown_at_s, frame_s, channels)
    if len(box.times_s) > 1:
        times = np.asarray(box.times_s, float)
        channels.append(Channel(node, "translation", times, np.array([k[0] for k in keyed])))
        channels.append(Channel(node, "rotation", times, quaternions))
