"""Checking an uploaded file against its declared media type before it is kept."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from services.pointcloud.ply import PLY_MEDIA_TYPE, PlyError, read_mesh, validate_ply
from supervisor.problems import Problem

MAX_JSON_BYTES = 256 * 1024 * 1024


def validate_upload(path: Path, *, media_type: str, name: str, kind: str) -> dict:
    """Returns metadata learned from the file; raises a 422 Problem if it is not valid.
    A ``mesh`` must be a PLY triangle mesh (panel meshes in the scene export)."""
    if kind == "mesh" and media_type != PLY_MEDIA_TYPE:
        raise Problem(422, f"kind=mesh: {name} must be a PLY triangle mesh ({PLY_MEDIA_TYPE}).")
    if media_type == PLY_MEDIA_TYPE:
        try:
            info = validate_ply(path)
            faces = len(read_mesh(path)[1]) if kind == "mesh" else None
        except PlyError as exc:
            what = "triangle mesh" if kind == "mesh" else "point cloud"
            raise Problem(422, f"{name} is not a valid PLY {what}: {exc}.") from exc
        meta = asdict(info)
        meta["grid_shape"] = list(info.grid_shape) if info.grid_shape else None
        if faces is not None:
            meta["faces"] = faces
        return {"ply": meta}
    if media_type == "application/json":
        if path.stat().st_size > MAX_JSON_BYTES:
            raise Problem(413, f"JSON artifacts are limited to {MAX_JSON_BYTES // 2**20} MiB.")
        try:
            with open(path, "rb") as handle:
                json.load(handle)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise Problem(422, f"{name} is not valid JSON: {exc}.") from exc
        return {}
    if media_type == "image/png":
        with open(path, "rb") as handle:
            if handle.read(8) != b"\x89PNG\r\n\x1a\n":
                raise Problem(422, f"{name} does not start with the PNG signature.")
    if media_type == "model/gltf-binary":
        with open(path, "rb") as handle:
            if handle.read(4) != b"glTF":
                raise Problem(422, f"{name} does not start with the GLB magic 'glTF'.")
    return {}
