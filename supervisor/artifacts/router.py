"""Artifacts: streamed upload (validated before it is kept), list, ranged download, delete."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.artifacts import service
from supervisor.artifacts.kinds import ARTIFACT_KINDS, ArtifactKindName
from supervisor.artifacts.schemas import ARTIFACT_KIND_PATTERN, MEDIA_TYPES, ArtifactOut
from supervisor.artifacts.validation import validate_upload
from supervisor.changes import record_change
from supervisor.deps import EDIT_ROLES, READ_ROLES, CurrentUser, get_runtime, get_session, require
from supervisor.engine.runtime import Runtime
from supervisor.idempotency import create_once
from supervisor.ids import IdPath
from supervisor.inspections.service import get as get_inspection
from supervisor.models import Artifact
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, decode_cursor, next_cursor
from supervisor.problems import Problem
from supervisor.storage import UploadTooLarge, safe_name

router = APIRouter(tags=["artifacts"])
readers = require(*READ_ROLES, action="read artifacts")
editors = require(*EDIT_ROLES, action="upload or delete artifacts")

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
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(editors),
) -> Response:
    """Upload a file. Its content is checked against what its kind needs before it is
    kept, whatever Content-Type was declared (a PLY — recognised by its magic line — for
    header, element sizes and finite coordinates; JSON parsed; PNG and GLB by signature),
    and the media type kept is the content's. Anything refused leaves nothing behind."""
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
    try:
        if received.size_bytes == 0:
            raise Problem(422, "The upload is empty.")
        media_type, meta = await run_in_threadpool(
            validate_upload, temp_path, media_type=media_type, name=name, kind=kind
        )
        return await run_in_threadpool(
            _store, request, runtime, user, inspection_id, kind, name, media_type, received, meta
        )
    finally:
        temp_path.unlink(missing_ok=True)


def _store(request, runtime, user, inspection_id, kind, name, media_type, received, meta):  # noqa: ANN001, ANN202
    final_uri: list[str] = []

    def create():  # noqa: ANN202
        get_inspection(session, inspection_id=inspection_id)
        uri = runtime.storage.commit(received.uri, inspection_id=inspection_id, name=name)
        final_uri.append(uri)
        artifact = Artifact(
            inspection_id=inspection_id,
            kind=kind,
            name=safe_name(name),
            media_type=media_type,
            size_bytes=received.size_bytes,
            sha256=received.sha256,
            storage_uri=uri,
            meta=meta,
            created_by=user.id,
        )
        session.add(artifact)
        session.flush()
        record_change(
            session,
            entity="artifact",
            entity_id=artifact.id,
            op="create",
            inspection_id=inspection_id,
            user_id=user.id,
        )
        body = ArtifactOut.model_validate(artifact).model_dump(mode="json")
        return body, f"/api/v1/inspections/{inspection_id}/artifacts/{artifact.id}"

    digest = f"{kind}\n{name}\n{media_type}\n{received.sha256}"
    with runtime.db.session(write=True) as session:
        try:
            response = create_once(
                request, session, user_id=user.id, body_digest=digest, create=create
            )
        except BaseException:
            for uri in final_uri:
                runtime.storage.delete(uri)
            raise
    if response.headers.get("Idempotent-Replayed"):
        for uri in final_uri:  # a concurrent duplicate committed first; ours is not needed
            runtime.storage.delete(uri)
    return response


@router.get("/inspections/{inspection_id}/artifacts", response_model=Page[ArtifactOut])
def list_artifacts(
    inspection_id: IdPath,
    kind: str | None = Query(None, pattern=ARTIFACT_KIND_PATTERN),
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = Depends(get_session),
    _: CurrentUser = Depends(readers),
) -> Page[ArtifactOut]:
    get_inspection(session, inspection_id=inspection_id)
    query = select(Artifact).where(
        Artifact.inspection_id == inspection_id, Artifact.id > decode_cursor(cursor)
    )
    if kind:
        query = query.where(Artifact.kind == kind)
    rows = session.scalars(query.order_by(Artifact.id).limit(limit + 1)).all()
    return Page[ArtifactOut](
        items=[ArtifactOut.model_validate(a) for a in rows[:limit]],
        next_cursor=next_cursor(rows, limit),
    )


@router.get("/inspections/{inspection_id}/artifacts/{artifact_id}", response_model=ArtifactOut)
def get_artifact(
    inspection_id: IdPath,
    artifact_id: IdPath,
    session: Session = Depends(get_session),
    _: CurrentUser = Depends(readers),
) -> Artifact:
    return service.get(session, inspection_id=inspection_id, artifact_id=artifact_id)


@router.get(
    "/inspections/{inspection_id}/artifacts/{artifact_id}/content",
    response_class=FileResponse,
    responses={
        200: {"content": {m: {} for m in MEDIA_TYPES}},
        206: {"description": "A byte range"},
    },
)
def download_artifact(
    inspection_id: IdPath,
    artifact_id: IdPath,
    session: Session = Depends(get_session),
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
    session: Session = Depends(get_session),
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(editors),
) -> Response:
    uri = service.delete(
        session, inspection_id=inspection_id, artifact_id=artifact_id, user_id=user.id
    )
    session.commit()
    runtime.storage.delete(uri)
    return Response(status_code=204)
