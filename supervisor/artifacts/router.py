"""Artifacts: streamed upload (validated before it is kept), list, ranged download, delete."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path, PurePath
from typing import Literal

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse
from sqlalchemy.orm import Session

from contract.artifacts import Inspected
from services.lib.pointcloud.reader import CANCELLED
from services.lib.pointcloud.scanner import UNITS_MM
from supervisor.artifacts import service
from supervisor.artifacts.schemas import (
    ARTIFACT_KIND_PATTERN,
    MEDIA_TYPES,
    ArtifactKindOut,
    ArtifactOut,
)
from supervisor.artifacts.validation import validate_upload
from supervisor.db import after_commit
from supervisor.deps import EDIT_ROLES, READ_ROLES, SESSION, CurrentUser, get_runtime, require
from supervisor.engine.registry import artifact_kinds
from supervisor.engine.runtime import Runtime
from supervisor.ids import IdPath
from supervisor.inspections.service import get as get_inspection
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page
from supervisor.problems import Problem
from supervisor.requests import JsonGuardRoute
from supervisor.storage import UploadTooLarge

router = APIRouter(route_class=JsonGuardRoute, tags=["artifacts"])
readers = require(*READ_ROLES, action="read artifacts")
editors = require(*EDIT_ROLES, action="upload or delete artifacts")
ARTIFACT_KINDS = artifact_kinds()
ArtifactKindName = Literal[tuple(ARTIFACT_KINDS)]  # the services' kinds, for the API schema

_UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "description": "The file itself as the raw body; its Content-Type is its media type.",
        "content": {m: {"schema": {"type": "string", "format": "binary"}} for m in MEDIA_TYPES},
    }
}


def _media_type(request: Request) -> str:
    declared = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if declared not in MEDIA_TYPES:
        accepted = ", ".join(sorted(MEDIA_TYPES))
        shown = declared or "none"
        raise Problem(
            415,
            f"Content-Type {shown!r} is not accepted for artifacts: send the file as the raw "
            f"request body with one of {accepted}.",
        )
    return declared


DISCONNECT_POLL_S = 0.5


async def _validate_while_connected(
    request: Request, path: Path, **upload: str | None
) -> Inspected:
    """``validate_upload`` in a worker thread, its cloud reader (if any) killed when the
    client goes away: nobody waits for the answer any more (a reader kept running up to
    900 s after its client had gone)."""
    gone = threading.Event()
    CANCELLED.set(gone)  # copied into the worker thread's context

    async def watch() -> None:
        while not await request.is_disconnected():
            await asyncio.sleep(DISCONNECT_POLL_S)
        gone.set()

    watcher = asyncio.create_task(watch())
    try:
        return await run_in_threadpool(validate_upload, path, **upload)
    finally:
        watcher.cancel()


@router.post(
    "/inspections/{inspection_id}/artifacts",
    status_code=201,
    response_model=ArtifactOut,
    openapi_extra=_UPLOAD_BODY,
)
async def upload_artifact(
    inspection_id: IdPath,
    request: Request,
    kind: ArtifactKindName = Query(
        description="What the file is: "
        + "; ".join(f"`{k.name}`: {k.description}" for k in ARTIFACT_KINDS.values())
    ),
    name: str = Query(min_length=1, max_length=255, description="File name, e.g. scan_000.ply"),
    units: Literal[tuple(UNITS_MM)] | None = Query(
        None,
        description="A point cloud's unit, when its format's convention does not hold: PLY "
        "and XYZ/ASC text are read as mm, PCD, LAS/LAZ and PTS as m, E57 is m by its "
        "standard; a nominal STL's (which says none: mm unless given).",
    ),
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(editors),
) -> Response:
    """Upload a file as the raw request body (not a form), its Content-Type one of the
    body's media types (415 otherwise), not empty and within the server's upload limit
    (413). Its content is checked against what its `kind` needs before it is kept,
    whatever Content-Type was declared (422 otherwise): a PLY — recognised by its magic
    line — for header, element sizes and finite coordinates; a point cloud a scanner or
    CloudCompare wrote (ASCII or big-endian PLY, PCD, LAS/LAZ, E57, XYZ/ASC, PTS —
    recognised by its content) converted to vista's PLY in mm, kept under its own name
    with `.ply` (`wing.e57` → `wing.ply`) with its source's format and unit in
    `meta.source`; a name the inspection's uploads hold already gets a number
    (`wing (2).ply`); JSON parsed; PNG, JPEG and GLB by
    signature; archives, models and trajectories read as their kind says. The media type
    kept is the content's. Anything refused leaves nothing behind."""
    media_type = _media_type(request)
    limit = runtime.settings.max_upload_bytes
    declared_length = request.headers.get("content-length")
    if declared_length is not None:
        if not declared_length.isdigit():
            raise Problem(400, "Content-Length must be a whole number of bytes.")
        if int(declared_length) > limit:
            raise Problem(413, f"The upload is larger than the limit of {limit // 2**20} MiB.")
    with runtime.db.read() as session:
        get_inspection(session, inspection_id=inspection_id)
    try:
        received = await runtime.storage.receive(request.stream(), limit_bytes=limit)
    except UploadTooLarge as exc:
        raise Problem(
            413, f"The upload is larger than the limit of {exc.limit_bytes // 2**20} MiB."
        ) from exc
    temp_path = runtime.storage.path(received.uri)
    found = None
    try:
        if received.size_bytes == 0:
            raise Problem(422, "The upload is empty.")
        found = await _validate_while_connected(
            request, temp_path, media_type=media_type, name=name, kind=kind, units=units
        )
        meta = found.meta
        if found.replacement is not None:  # the file sent, named in what is kept of it
            sent = {"name": name, "size_bytes": received.size_bytes, "sha256": received.sha256}
            meta = {**meta, "source": {**meta.get("source", {}), **sent}}
            received = await run_in_threadpool(runtime.storage.adopt, found.replacement)
            name = f"{PurePath(name).stem}{MEDIA_TYPES[found.media_type]}"
        upload = service.Upload(inspection_id, kind, name, found.media_type, received, meta)
        return await run_in_threadpool(service.store, request, runtime, user, upload)
    finally:
        temp_path.unlink(missing_ok=True)
        if found is not None and found.replacement is not None:
            found.replacement.unlink(missing_ok=True)


@router.get("/artifact-kinds", response_model=list[ArtifactKindOut])
def list_artifact_kinds(_: CurrentUser = Depends(readers)) -> list[ArtifactKindOut]:
    """The kinds of file an upload may be (the services' declared list), with what each is."""
    return [
        ArtifactKindOut(name=k.name, description=k.description) for k in ARTIFACT_KINDS.values()
    ]


@router.get("/inspections/{inspection_id}/artifacts", response_model=Page[ArtifactOut])
def list_artifacts(
    inspection_id: IdPath,
    kind: str | None = Query(None, pattern=ARTIFACT_KIND_PATTERN),
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> Page[ArtifactOut]:
    return service.page(
        session, inspection_id=inspection_id, kind=kind or None, cursor=cursor, limit=limit
    )


@router.get("/inspections/{inspection_id}/artifacts/{artifact_id}", response_model=ArtifactOut)
def get_artifact(
    inspection_id: IdPath,
    artifact_id: IdPath,
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> ArtifactOut:
    found = service.get(session, inspection_id=inspection_id, artifact_id=artifact_id)
    return service.artifacts_out(session, [found])[0]


@router.get(
    "/inspections/{inspection_id}/artifacts/{artifact_id}/content",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The file, with the media type it was kept with.",
            "content": {m: {} for m in MEDIA_TYPES},
        }
    },
)
def download_artifact(
    inspection_id: IdPath,
    artifact_id: IdPath,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
    _: CurrentUser = Depends(readers),
) -> FileResponse:
    """The file, with HTTP Range support (``Range: bytes=0-1023``) and its sha256 as ETag."""
    artifact = service.get(session, inspection_id=inspection_id, artifact_id=artifact_id)
    path = runtime.storage.path(artifact.storage_uri)
    if not path.exists():
        raise Problem(410, f"The file of artifact {artifact_id} is missing from storage.")
    return FileResponse(
        path,
        media_type=artifact.media_type,
        filename=artifact.name,
        headers={"ETag": f'"{artifact.sha256}"'},
    )


@router.delete("/inspections/{inspection_id}/artifacts/{artifact_id}", status_code=204)
def delete_artifact(
    inspection_id: IdPath,
    artifact_id: IdPath,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(editors),
) -> Response:
    uri = service.delete(
        session, inspection_id=inspection_id, artifact_id=artifact_id, actor=user, role=user.role
    )
    after_commit(session, lambda: runtime.storage.delete(uri))
    return Response(status_code=204)
