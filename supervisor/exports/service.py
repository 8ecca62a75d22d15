"""The inspection's scene file: built once per version (its ETag), cached on disk."""

from __future__ import annotations

import hashlib
from typing import BinaryIO

from supervisor.engine.runtime import Runtime
from supervisor.exports.cache import open_cached, publish, remove_others
from supervisor.exports.etag import scene_etag
from supervisor.inspections.service import get as get_inspection


def _matches(if_none_match: str | None, etag: str) -> bool:
    if not if_none_match:
        return False
    tags = [t.strip().removeprefix("W/") for t in if_none_match.split(",")]
    return "*" in tags or etag in tags


def scene_file(
    runtime: Runtime,
    inspection_id: int,
    max_points: int,
    if_none_match: str | None,
    run_id: int | None = None,
) -> tuple[str, BinaryIO | None]:
    """(ETag, cached file open for reading) of the scene of run ``run_id`` (None: the
    inspection's newest measured run's) as it is now, built if not cached yet; no file when
    the client has this version already. One file is kept per run shown."""
    from supervisor.exports.scene import build_scene, gather, shown_run

    with runtime.db.read() as session:
        inspection = get_inspection(session, inspection_id=inspection_id)
        etag = scene_etag(
            session, inspection_id=inspection_id, max_points=max_points, run_id=run_id
        )
        if _matches(if_none_match, etag):
            return etag, None
        folder = runtime.storage.export_dir(inspection_id)
        shown = f"run{run_id}" if run_id is not None else "newest"
        path = folder / f"scene-{shown}-{hashlib.sha256(etag.encode()).hexdigest()[:24]}.glb"
        if (cached := open_cached(path)) is not None:
            return etag, cached
        # which run it shows (a 404 for a run with none) is asked only when it is built: the
        # ETag and the cache answer every other request without it
        run = shown_run(session, inspection_id=inspection_id, run_id=run_id)
        source = gather(session, runtime.storage, inspection=inspection, run=run)
    handle = publish(path, build_scene(source, max_points=max_points, etag=etag))
    remove_others(folder, f"scene-{shown}-*.glb", path)
    return etag, handle
