"""Artifacts: keeping an upload, finding one, deleting one."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import PurePath

from fastapi import Request, Response
from sqlalchemy import insert, select
from sqlalchemy.orm import Session

from supervisor.artifacts.schemas import ArtifactOut
from supervisor.audit.service import Actor, audit
from supervisor.changes import record_change
from supervisor.db import commit
from supervisor.engine.runtime import Runtime
from supervisor.idempotency import create_once
from supervisor.inspections.service import ensure_live
from supervisor.inspections.service import get as get_inspection
from supervisor.models import Artifact, Inspection, Job, User
from supervisor.models.jobs import UNFINISHED
from supervisor.pagination import Page, paginate
from supervisor.problems import Problem, not_found
from supervisor.storage import StoredFile, safe_name


def get(session: Session, *, inspection_id: int, artifact_id: int) -> Artifact:
    artifact = session.get(Artifact, artifact_id)
    if artifact is None or artifact.inspection_id != inspection_id:
        raise not_found(f"artifact in inspection {inspection_id}", artifact_id)
    ensure_live(session, inspection_id, f"artifact in inspection {inspection_id}", artifact_id)
    return artifact


def delete(
    session: Session, *, inspection_id: int, artifact_id: int, actor: Actor, role: str
) -> str:
    """Delete the row (its uploader, the inspection's owner or an admin); returns the
    storage uri to remove once the transaction committed."""
    artifact = get(session, inspection_id=inspection_id, artifact_id=artifact_id)
    owner = session.scalar(select(Inspection.created_by).where(Inspection.id == inspection_id))
    if role != "admin" and actor.id not in (artifact.created_by, owner):
        raise Problem(
            403,
            f"Only who uploaded artifact {artifact_id}, the inspection's owner or an admin "
            "may delete it.",
        )
    unfinished = session.scalars(
        select(Job).where(Job.inspection_id == inspection_id, Job.status.in_(UNFINISHED))
    ).all()
    readers = [job.id for job in unfinished if artifact_id in (job.input_artifact_ids or [])]
    if readers:
        raise Problem(409, f"Artifact {artifact_id} is an input of unfinished job(s) {readers}.")
    uri = artifact.storage_uri
    session.delete(artifact)
    record_change(
        session,
        entity="artifact",
        entity_id=artifact_id,
        op="delete",
        inspection_id=inspection_id,
        user_id=actor.id,
    )
    audit(
        session,
        actor,
        "delete",
        entity="artifact",
        entity_id=artifact_id,
        inspection_id=inspection_id,
        before={"name": artifact.name, "kind": artifact.kind, "sha256": artifact.sha256},
    )
    return uri


COMPOUND_SUFFIXES = (".tar.gz", ".tar.bz2", ".tar.xz")


def unique_name(session: Session, inspection_id: int, kind: str, name: str) -> str:
    """``name`` as kept (``safe_name``), or, when the inspection holds an upload of that
    kind and name already, the first free ``stem (n).ext`` (``wing.ply``, ``wing (2).ply``,
    …). Files of different kinds may share a name: a depth map is matched to its image by
    it."""
    name = safe_name(name)
    taken = set(
        session.scalars(
            select(Artifact.name).where(
                Artifact.inspection_id == inspection_id,
                Artifact.kind == kind,
                Artifact.job_id.is_(None),
            )
        )
    )
    if name not in taken:
        return name
    suffix = next((s for s in COMPOUND_SUFFIXES if name.endswith(s)), PurePath(name).suffix)
    stem = name[: len(name) - len(suffix)] if suffix else name
    number = 2
    while f"{stem} ({number}){suffix}" in taken:
        number += 1
    return f"{stem} ({number}){suffix}"


def artifacts_out(session: Session, artifacts: list[Artifact]) -> list[ArtifactOut]:
    """Each artifact with the run and step of the job that made it and its uploader's name."""
    job_ids = {a.job_id for a in artifacts if a.job_id is not None}
    user_ids = {a.created_by for a in artifacts if a.created_by is not None}
    jobs = {
        j.id: j
        for j in session.execute(select(Job.id, Job.run_id, Job.step).where(Job.id.in_(job_ids)))
    }
    names = dict(session.execute(select(User.id, User.username).where(User.id.in_(user_ids))).all())
    out = []
    for artifact in artifacts:
        item = ArtifactOut.model_validate(artifact)
        job = jobs.get(artifact.job_id)
        item.run_id, item.step = (job.run_id, job.step) if job is not None else (None, None)
        item.created_by_name = names.get(artifact.created_by)
        out.append(item)
    return out


def record_artifact(
    session: Session,
    *,
    inspection_id: int,
    kind: str,
    name: str,
    media_type: str,
    stored: StoredFile,
    meta: dict,
    job_id: int | None = None,
    created_by: int | None = None,
) -> int:
    """The one way an artifact's row comes to be (an upload's, a job output's): the row
    and its change-log entry; returns its id. ``stored`` is already in its final place."""
    artifact_id = session.execute(
        insert(Artifact)
        .values(
            inspection_id=inspection_id,
            kind=kind,
            name=safe_name(name),
            media_type=media_type,
            size_bytes=stored.size_bytes,
            sha256=stored.sha256,
            storage_uri=stored.uri,
            meta=meta,
            job_id=job_id,
            created_by=created_by,
        )
        .returning(Artifact.id)
    ).scalar_one()
    record_change(
        session,
        entity="artifact",
        entity_id=artifact_id,
        op="create",
        inspection_id=inspection_id,
        user_id=created_by,
    )
    return artifact_id


@dataclass(frozen=True)
class Upload:
    """A file received and checked, to be kept as an artifact of ``inspection_id``."""

    inspection_id: int
    kind: str
    name: str
    media_type: str
    received: StoredFile
    """The file in storage's incoming area."""
    meta: dict


def store(request: Request, runtime: Runtime, actor: Actor, upload: Upload) -> Response:
    """Keep the upload (its file moved into the inspection's folder, its row and change
    written) once per Idempotency-Key; the response to send. The upload is read before
    the transaction starts, so this holds the write lock only while it stores the row
    (and runs its own transaction, not the request's); a file whose row did not commit
    is deleted."""
    final_uri: list[str] = []

    def create() -> tuple[dict, str]:
        get_inspection(session, inspection_id=upload.inspection_id)
        name = unique_name(session, upload.inspection_id, upload.kind, upload.name)
        uri = runtime.storage.commit(
            upload.received.uri, inspection_id=upload.inspection_id, name=name
        )
        final_uri.append(uri)
        artifact_id = record_artifact(
            session,
            inspection_id=upload.inspection_id,
            kind=upload.kind,
            name=name,
            media_type=upload.media_type,
            stored=replace(upload.received, uri=uri),
            meta=upload.meta,
            created_by=actor.id,
        )
        audit(
            session,
            actor,
            "upload",
            entity="artifact",
            entity_id=artifact_id,
            inspection_id=upload.inspection_id,
            after={
                "name": name,
                "kind": upload.kind,
                "size_bytes": upload.received.size_bytes,
                "sha256": upload.received.sha256,
            },
        )
        artifact = session.get(Artifact, artifact_id)
        body = artifacts_out(session, [artifact])[0].model_dump(mode="json")
        return body, f"/api/v1/inspections/{upload.inspection_id}/artifacts/{artifact_id}"

    digest = f"{upload.kind}\n{upload.name}\n{upload.media_type}\n{upload.received.sha256}"
    with runtime.db.session(write=True) as session:
        try:
            response = create_once(
                request, session, user_id=actor.id, body_digest=digest, create=create
            )
            commit(session)
        except BaseException:
            for uri in final_uri:
                runtime.storage.delete(uri)
            raise
    if response.headers.get("Idempotent-Replayed"):
        for uri in final_uri:  # a concurrent duplicate committed first; ours is not needed
            runtime.storage.delete(uri)
    return response


def page(
    session: Session, *, inspection_id: int, kind: str | None, cursor: str | None, limit: int
) -> Page[ArtifactOut]:
    """The inspection's artifacts (of one kind, if given) after ``cursor``."""
    get_inspection(session, inspection_id=inspection_id)
    return paginate(
        session,
        select(Artifact).where(Artifact.inspection_id == inspection_id),
        equal={Artifact.kind: kind},
        cursor=cursor,
        limit=limit,
        item=ArtifactOut,
        out=lambda rows: artifacts_out(session, rows),
    )
