"""Checking an uploaded file against its declared media type before it is kept."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from services.pointcloud.ply import PLY_MEDIA_TYPE, PlyError, validate_ply
from supervisor.problems import Problem

MAX_JSON_BYTES = 256 * 1024 * 1024


def validate_upload(path: Path, *, media_type: str, name: str) -> dict:
    """Returns metadata learned from the file; raises a 422 Problem if it is not valid."""
    if media_type == PLY_MEDIA_TYPE:
        try:
            info = validate_ply(path)
        except PlyError as exc:
            raise Problem(422, f"{name} is not a valid PLY point cloud: {exc}.") from exc
        meta = asdict(info)
        meta["grid_shape"] = list(info.grid_shape) if info.grid_shape else None
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
