"""An inspection's 3D scene as glTF: the scene of what is judged — one run's measurement:
the cloud its measuring job read, decimated to a budget, what that job presents on it
(outlines, seams), the defects that run found (and those added by hand), panel meshes, and
one anchor node per image marker. The inspection's scene is its newest measured run's; any
other measured run's scene is asked for by its id (``scene_runs`` lists them). Before any
measurement the scene is the newest uploaded cloud with the defects added by hand.

Node layout (names are stable; clients find things by them)::

    inspection-<id>           extras: the run shown (``scene_run``)
    ├── cloud                 POINTS with COLOR_0 (the cloud the run measured)
    ├── panels-<artifact id>  triangles (each `mesh` artifact), if any
    ├── <group>               each job kind's presented results, drawn from the newest
    │   └── <line>            output it reads (``contract.scene``): the measurement's
    │                         ``outlines`` (``panel-<id>``) and ``seams`` (``seam-<id>``)
    ├── defects
    │   └── defect-<id>       a ring around the defect at its extent, facing along its
    │                         normal (it circles what it marks); extras: id, type, value, …
    └── anchors
        └── marker-<name>     the image marker's pose; extras: name, area, size_mm, image
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
from sqlalchemy import or_, select
from sqlalchemy.orm import Session

from contract.kinds import Presenter
from contract.scene import LineGroup
from services.lib.pointcloud.ply import PLY_MEDIA_TYPE
from supervisor.defects.service import reading
from supervisor.engine.registry import all_kinds, get_kind, load_kinds
from supervisor.exports.gltf import (
    GLTF_R_BASE,
    GLTF_T_BASE,
    Material,
    Mesh,
    Node,
    base_to_gltf,
    pose_to_gltf,
    ring,
    rotation_from_y,
    write_glb,
)
from supervisor.jobs.service import input_artifacts
from supervisor.models import Artifact, Defect, Inspection, Job, Run
from supervisor.problems import Problem
from supervisor.storage import Storage

MARKER_MM = (6.0, 40.0)
"""Marker ring diameters: the defect's extent within these bounds. The smallest keeps a
0.5 mm dent visible and pickable; the largest keeps a 140 mm stretch of seam readable (its
whole extent is in the node's extras)."""
RING_SEGMENTS = 48

TYPE_COLORS = {
    "gap": "#e6194b",
    "step": "#f58231",
    "parallelism": "#ffe119",
    "mismatch": "#911eb4",
    "scratch": "#4363d8",
    "dent": "#3cb44b",
    "bump": "#9a6324",
    "color": "#f032e6",
    "deviation": "#42d4f4",
}
"""One distinct colour per type (the dashboard's legend uses the same ones)."""
PANEL_COLOR = (0.78, 0.80, 0.84, 0.55)
MOST_SURFACE_TRIANGLES = 1_000_000
"""A surface (nominal panels, a part's nominal) of more triangles is not drawn: its id is
in the scene's ``not_drawn``."""


def rgba(hex_colour: str) -> tuple[float, float, float, float]:
    value = int(hex_colour.lstrip("#"), 16)
    return (
        round((value >> 16) / 255, 4),
        round((value >> 8 & 255) / 255, 4),
        round((value & 255) / 255, 4),
        1.0,
    )


@dataclass(frozen=True)
class SceneRun:
    """A run whose measurement a scene can show: its newest succeeded job of a kind that
    presents results, and the cloud that job read."""

    run_id: int
    run_name: str
    job_id: int
    """The measuring job."""
    kind: str
    step: str
    finished_at: datetime | None
    cloud_artifact_id: int
    """The cloud it read."""
    cloud_name: str


def scene_runs(session: Session, *, inspection_id: int) -> list[SceneRun]:
    """The inspection's measured runs, newest first (a run whose cloud was deleted has no
    scene left to show and is left out)."""
    over = {k.name: k.shows.inspection.over for k in all_presenting_kinds()}
    jobs = session.scalars(
        select(Job)
        .where(Job.inspection_id == inspection_id, Job.kind.in_(over), Job.status == "succeeded")
        .order_by(Job.finished_at.desc(), Job.id.desc())
    ).all()
    runs: dict[int, SceneRun] = {}
    for job in jobs:
        if job.run_id in runs:
            continue
        clouds = [a for a in input_artifacts(session, job) if a.kind == over[job.kind]]
        if not clouds:
            continue
        run_name = session.scalar(select(Run.name).where(Run.id == job.run_id)) or ""
        runs[job.run_id] = SceneRun(
            job.run_id,
            run_name,
            job.id,
            job.kind,
            job.step,
            job.finished_at,
            clouds[0].id,
            clouds[0].name,
        )
    return list(runs.values())


def scene_run_doc(run: SceneRun | None) -> dict | None:
    """The run a scene shows, JSON-able (None: no measurement yet)."""
    if run is None:
        return None
    return asdict(run) | {"finished_at": run.finished_at.isoformat() if run.finished_at else None}


def shown_run(session: Session, *, inspection_id: int, run_id: int | None) -> SceneRun | None:
    """The run a scene shows: ``run_id``'s (a 404 naming why when it has none), else the
    newest measured run's; None before any measurement."""
    runs = scene_runs(session, inspection_id=inspection_id)
    if run_id is None:
        return runs[0] if runs else None
    for run in runs:
        if run.run_id == run_id:
            return run
    raise Problem(
        404,
        f"Run {run_id} of inspection {inspection_id} has no scene: it is not one of its runs, "
        "its measurement has not succeeded, or the cloud it measured was deleted.",
    )


@dataclass(frozen=True)
class SceneSource:
    """What one export reads: rows and files, gathered in one database session."""

    inspection_id: int
    markers: list[dict]
    defects: list[dict]
    cloud_path: Path | None
    cloud_artifact_id: int | None
    meshes: list[tuple[int, Path]]
    presented: tuple[tuple[Presenter, Path], ...] = ()
    """The measuring job's kind's presenter with the file it reads."""
    run: SceneRun | None = None


def gather(
    session: Session, storage: Storage, *, inspection: Inspection, run: SceneRun | None
) -> SceneSource:
    """The scene of ``run`` (``shown_run``): its cloud, its job's presented results, its
    defects and those added by hand; without a run, the newest cloud, the results and the
    defects added by hand."""
    belongs = (
        Defect.run_id.is_(None)
        if run is None
        else or_(Defect.run_id.is_(None), Defect.run_id == run.run_id)
    )
    defects = [
        row._asdict()
        for row in session.execute(
            select(
                Defect.id,
                Defect.type,
                Defect.value_mm,
                Defect.tolerance_mm,
                Defect.measurements,
                Defect.location_mm,
                Defect.normal,
                Defect.extent_mm,
                Defect.confidence,
            )
            .where(Defect.inspection_id == inspection.id, belongs)
            .order_by(Defect.id)
        )
    ]
    if run is None:  # no measurement yet: the newest cloud, and results uploaded by hand
        presenters = [k.shows.inspection for k in all_presenting_kinds()]
    else:
        kind = get_kind(run.kind)
        presenters = [kind.shows.inspection] if kind and kind.shows.inspection else []
    presenters = list(dict.fromkeys(presenters))
    run_jobs = select(Job.id).where(Job.run_id == (run.run_id if run else -1))
    meshes = session.execute(
        select(Artifact.id, Artifact.storage_uri)
        .where(
            Artifact.inspection_id == inspection.id,
            Artifact.kind.in_({kind for p in presenters for kind in p.surfaces}),
            or_(Artifact.job_id.is_(None), Artifact.job_id.in_(run_jobs)),
        )
        .order_by(Artifact.id)
    ).all()
    clouds = select(Artifact).where(
        Artifact.inspection_id == inspection.id,
        Artifact.kind.in_({p.over for p in presenters}),
        Artifact.media_type == PLY_MEDIA_TYPE,
    )
    if run is None:
        cloud = session.scalar(clouds.order_by(Artifact.id.desc()).limit(1))
        reads = Artifact.job_id.is_(None)
    else:
        cloud = session.scalar(clouds.where(Artifact.id == run.cloud_artifact_id))
        reads = Artifact.job_id == run.job_id
        drawn = presenters[0].points if presenters else None
        if drawn is not None:  # the run's own points: its scan as it compared it
            cloud = (
                session.scalar(
                    select(Artifact).where(
                        reads, Artifact.kind == drawn.kind, Artifact.name == drawn.file_name()
                    )  # fmt: skip
                )
                or cloud
            )
    presented = []
    for presenter in presenters:
        newest = session.scalar(
            select(Artifact.storage_uri)
            .where(
                Artifact.inspection_id == inspection.id,
                reads,
                Artifact.kind == presenter.reads.kind,
                Artifact.name == presenter.reads.file_name(),
            )
            .order_by(Artifact.id.desc())
            .limit(1)
        )
        if newest:
            presented.append((presenter, storage.path(newest)))
    return SceneSource(
        inspection_id=inspection.id,
        markers=list(inspection.markers or []),
        defects=defects,
        cloud_path=storage.path(cloud.storage_uri) if cloud else None,
        cloud_artifact_id=cloud.id if cloud else None,
        meshes=[(a.id, storage.path(a.storage_uri)) for a in meshes],
        presented=tuple(presented),
        run=run,
    )


def all_presenting_kinds() -> list:
    """The job kinds that present results in an inspection's scene."""
    if not all_kinds():
        load_kinds()
    return [k for k in all_kinds() if k.shows.inspection is not None]


def _cloud_colors(colors: np.ndarray | None, points_m: np.ndarray) -> np.ndarray:
    """(N, 4) RGBA bytes: the scan's colours, or grey shaded by height where it has none."""
    rgba = np.full((len(points_m), 4), 255, dtype=np.uint8)
    if colors is not None:
        rgba[:, :3] = colors
        return rgba
    up = points_m[:, 1]
    span = max(float(np.ptp(up)), 1e-9)
    rgba[:, :3] = (90 + 140 * (up - up.min()) / span).astype(np.uint8)[:, None]
    return rgba


def _defect_extras(defect: dict) -> dict:
    """A finding's marker data: what it is and where, as measured. Its status, severity,
    limit and reviewers' verdicts are not here: they change without the geometry and come
    with the sync's defect data (the scene's ETag follows its geometry only)."""
    measurements = defect["measurements"] or {}
    read = reading(defect["value_mm"], defect["tolerance_mm"], measurements)
    return {
        "defect_id": defect["id"],
        "type": defect["type"],
        "value": read["value"],
        "unit": read["unit"],
        **{k: measurements[k] for k in ("sigma_mm",) if k in measurements},
        "confidence": defect["confidence"],
        "location_mm": defect["location_mm"],
        "normal": defect["normal"],
        "extent_mm": defect["extent_mm"],
    }


def add_line_groups(
    groups: tuple[LineGroup, ...],
    meshes: list[Mesh],
    materials: list[Material],
    nodes: list[Node],
    top: list[int],
) -> None:
    """Each group's lines under a group node, a node per line with its extras."""
    for group in groups:
        lines = [(p.name, p.points_mm, p.shape, p.extras) for p in group.lines]
        _add_lines(
            group.name,
            lines,
            Material(group.material, group.colour_rgba),
            meshes,
            materials,
            nodes,
            top,
        )


def _add_lines(
    group_name: str,
    lines: list[tuple[str, list, str, dict]],
    material: Material,
    meshes: list[Mesh],
    materials: list[Material],
    nodes: list[Node],
    top: list[int],
) -> None:
    """One node per (name, points in mm, ``loop``/``strip``, extras) under ``group_name``."""
    if not lines:
        return
    materials.append(material)
    group = Node(group_name, children=[])
    nodes.append(group)
    top.append(len(nodes) - 1)
    for name, points_mm, mode, extras in lines:
        meshes.append(Mesh(name, base_to_gltf(points_mm), material=len(materials) - 1, lines=mode))
        group.children.append(len(nodes))
        nodes.append(Node(name, mesh=len(meshes) - 1, extras=extras))


def build_scene(source: SceneSource, *, max_points: int, etag: str) -> bytes:
    """The GLB of ``source`` (see the module docstring for its layout)."""
    from services.lib.pointcloud.nominal import read_nominal
    from services.lib.pointcloud.ply import read_ply_sample

    meshes: list[Mesh] = []
    used = {d["type"] for d in source.defects}
    materials = [
        Material(f"defect-{t}", rgba(colour), double_sided=True)
        for t, colour in TYPE_COLORS.items()
        if t in used
    ]
    nodes: list[Node] = [Node(f"inspection-{source.inspection_id}")]
    top: list[int] = []
    extras = {
        "units": "metre",
        "up": "+Y",
        "converted_from": "vista base frame: millimetres, +Z up",
        "gltf_T_base": GLTF_T_BASE.tolist(),
        "inspection_id": source.inspection_id,
        "scene_etag": etag,
        "scene_run": scene_run_doc(source.run),
    }
    if source.cloud_path is not None:
        cloud = read_ply_sample(source.cloud_path, max_points)
        if len(cloud.points):
            points = base_to_gltf(cloud.points)
            meshes.append(Mesh("cloud", points, colors=_cloud_colors(cloud.colors, points)))
            nodes.append(Node("cloud", mesh=len(meshes) - 1))
            top.append(len(nodes) - 1)
            extras["cloud"] = {"artifact_id": source.cloud_artifact_id, "points": len(points)}
    if source.meshes:
        materials.append(Material("panel", PANEL_COLOR, double_sided=True))
    for artifact_id, path in source.meshes:
        nominal = read_nominal(path)  # a PLY mesh, or a part's nominal in any format
        if len(nominal.mesh.faces) > MOST_SURFACE_TRIANGLES:
            extras.setdefault("not_drawn", []).append(artifact_id)
            continue
        meshes.append(
            Mesh(
                f"panels-{artifact_id}",
                base_to_gltf(np.asarray(nominal.mesh.vertices_mm)),
                indices=np.asarray(nominal.mesh.faces),
                material=len(materials) - 1,
            )
        )
        nodes.append(Node(f"panels-{artifact_id}", mesh=len(meshes) - 1))
        top.append(len(nodes) - 1)
    for presenter, path in source.presented:
        add_line_groups(presenter.load()(path), meshes, materials, nodes, top)
    ring_vertices, ring_faces = ring(RING_SEGMENTS)
    ring_normals = np.tile(np.float32([0, 1, 0]), (len(ring_vertices), 1))
    marker_mesh = {}
    for defect_type in sorted({d["type"] for d in source.defects}, key=list(TYPE_COLORS).index):
        material = [m.name for m in materials].index(f"defect-{defect_type}")
        meshes.append(
            Mesh(
                f"marker-{defect_type}",
                ring_vertices,
                normals=ring_normals,
                indices=ring_faces,
                material=material,
            )
        )
        marker_mesh[defect_type] = len(meshes) - 1
    if source.defects:
        group = Node("defects", children=[])
        nodes.append(group)
        top.append(len(nodes) - 1)
        locations = base_to_gltf([d["location_mm"] for d in source.defects], np.float64)
        normals = np.asarray([d["normal"] for d in source.defects], float) @ GLTF_R_BASE.T
        for defect, at, normal in zip(source.defects, locations, normals, strict=True):
            radius_m = float(np.clip(defect["extent_mm"], *MARKER_MM)) / 2000.0
            group.children.append(len(nodes))
            nodes.append(
                Node(
                    f"defect-{defect['id']}",
                    mesh=marker_mesh[defect["type"]],
                    translation=[float(c) for c in at],
                    rotation=rotation_from_y(normal),
                    scale=[radius_m] * 3,
                    extras=_defect_extras(defect),
                )
            )
    anchors = Node("anchors", children=[])
    if source.markers:
        nodes.append(anchors)
        top.append(len(nodes) - 1)
    for marker in source.markers:
        translation, rotation = pose_to_gltf(np.array(marker["base_T_marker"]))
        anchors.children.append(len(nodes))
        nodes.append(
            Node(
                f"marker-{marker['name']}",
                translation=translation,
                rotation=rotation,
                extras={
                    "marker": marker["name"],
                    "area": marker["area"],
                    "size_mm": marker["size_mm"],
                    "image": marker.get("image", ""),
                    "base_T_marker": marker["base_T_marker"],
                },
            )
        )
    nodes[0] = Node(nodes[0].name, children=top)
    return write_glb(
        meshes=meshes, materials=materials, nodes=nodes, roots=[0], asset_extras=extras
    )
