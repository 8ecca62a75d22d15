"""STEP (ISO 10303-21: AP203, AP214, AP242) nominals through Open CASCADE
(``cadquery-ocp``): the file's shapes transferred, every B-rep face tessellated to a chordal
tolerance, each face one region (``face N``, in the file's order), reversed faces turned so
that every normal points out of the material. Lengths come in mm (Open CASCADE converts the
file's unit). Also what the simulators use to write a part's STEP.

Open CASCADE hands its triangulations out node by node, so reading them is a loop over a
face's nodes in Python: a STEP of a few hundred faces at 0.01 mm chord is some 10⁵ nodes,
well under a second.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.lib.pointcloud.mesh_distance import TriangleMesh

INSTALL = "pip install cadquery-ocp (the README's set-up installs it: `make install`)"


def available() -> bool:
    try:
        import OCP  # noqa: F401
    except ImportError:
        return False
    return True


def read_step(path: Path, *, chord_mm: float, angle_deg: float
              ) -> tuple[TriangleMesh, np.ndarray, tuple[str, ...]]:  # fmt: skip
    """The STEP at ``path`` tessellated: its mesh, each triangle's face, the faces' names."""
    if not available():
        raise ValueError(f"reading STEP needs Open CASCADE: {INSTALL}")
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_Reader

    reader = STEPControl_Reader()
    if reader.ReadFile(str(path)) != IFSelect_RetDone:
        raise ValueError("Open CASCADE could not read it as ISO 10303-21 (STEP)")
    if reader.TransferRoots() == 0:
        raise ValueError("it holds no shape Open CASCADE can transfer")
    return tessellate(reader.OneShape(), chord_mm=chord_mm, angle_deg=angle_deg)


def tessellate(shape: object, *, chord_mm: float, angle_deg: float
               ) -> tuple[TriangleMesh, np.ndarray, tuple[str, ...]]:  # fmt: skip
    from OCP.BRep import BRep_Tool
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS

    BRepMesh_IncrementalMesh(shape, chord_mm, False, np.radians(angle_deg), True)
    vertices, faces, regions, names = [], [], [], []
    offset = 0
    explorer = TopExp_Explorer(shape, TopAbs_FACE)
    while explorer.More():
        face = TopoDS.Face(explorer.Current())
        explorer.Next()
        location = TopLoc_Location()
        triangulation = BRep_Tool.Triangulation_s(face, location)
        if triangulation is None or triangulation.NbTriangles() == 0:
            continue
        move = location.Transformation()
        nodes = np.array(
            [
                triangulation.Node(i).Transformed(move).Coord()
                for i in range(1, triangulation.NbNodes() + 1)
            ]
        )
        corners = (
            np.array(
                [
                    triangulation.Triangle(i).Get()
                    for i in range(1, triangulation.NbTriangles() + 1)
                ],
                dtype=np.int64,
            )
            - 1
        )
        if face.Orientation() == TopAbs_REVERSED:
            corners = corners[:, ::-1]
        names.append(f"face {len(names) + 1}")
        vertices.append(nodes)
        faces.append(corners + offset)
        regions.append(np.full(len(corners), len(names) - 1))
        offset += len(nodes)
    if not faces:
        raise ValueError("none of its faces could be tessellated")
    # faces meeting at an edge share its nodes (Open CASCADE meshes an edge once): one
    # vertex each, so that the edge's pseudo-normal is both faces'
    shared, index = np.unique(np.vstack(vertices), axis=0, return_inverse=True)
    mesh = TriangleMesh(shared, index.ravel()[np.vstack(faces)])
    return mesh, np.concatenate(regions), tuple(names)


def write_step(path: Path, shape: object) -> None:
    """``shape`` as an AP214 STEP file."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    writer = STEPControl_Writer()
    writer.Transfer(shape, STEPControl_AsIs)
    if writer.Write(str(path)) != IFSelect_RetDone:
        raise OSError(f"Open CASCADE could not write {path}")
