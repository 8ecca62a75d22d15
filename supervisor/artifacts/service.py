from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.changes import record_change
from supervisor.models import Artifact, Job
from supervisor.models.jobs import UNFINISHED
from supervisor.problems import Problem, not_found


def get(session: Session, *, inspection_id: int, artifact_id: int) -> Artifact:
    artifact = session.get(Artifact, artifact_id)
    if artifact is None or artifact.inspection_id != inspection_id:
        raise not_found(f"artifact in inspection {inspection_id}", artifact_id)
    return artifact


def delete(session: Session, *, inspection_id: int, artifact_id: int, user_id: int) -> str:
    """Delete the row; returns the storage uri to remove once the transaction committed."""
    artifact = get(session, inspection_id=inspection_id, artifact_id=artifact_id)
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
        user_id=user_id,
    )
    return uri
