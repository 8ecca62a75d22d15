from __future__ import annotations

from pydantic import ValidationError
from sqlalchemy import ColumnElement, exists, select
from sqlalchemy.orm import Session

from contract.tolerances import Tolerances, merge_tolerances
from supervisor.audit.service import Actor, audit, changed_fields
from supervisor.changes import add_created, record_change, record_update
from supervisor.defects.rejudge import rejudge_findings
from supervisor.inspections.schemas import InspectionCreate, InspectionUpdate
from supervisor.models import Defect, Inspection, Job
from supervisor.models._types import utcnow
from supervisor.models.jobs import UNFINISHED
from supervisor.problems import Problem, not_found

OWNER_ONLY_FIELDS = ("tolerances",)
"""Fields only the owner or an admin may change (closing and reopening too: see
``check_owner``)."""


def get(session: Session, *, inspection_id: int) -> Inspection:
    """The inspection; 404 when there is none or it is in the trash."""
    inspection = session.get(Inspection, inspection_id)
    if inspection is None or inspection.deleted_at is not None:
        raise not_found("inspection", inspection_id)
    return inspection


def ensure_live(session: Session, inspection_id: int, what: str, ident: object) -> None:
    """404 for ``what`` when its inspection went to the trash (its rows stay until purged)."""
    deleted = session.scalar(select(Inspection.deleted_at).where(Inspection.id == inspection_id))
    if deleted is not None:
        raise not_found(what, ident)


def live(inspection_id: ColumnElement[int]) -> ColumnElement[bool]:
    """A filter keeping rows whose inspection is not in the trash."""
    return inspection_id.not_in(select(Inspection.id).where(Inspection.deleted_at.is_not(None)))


def valid_tolerances(document: dict) -> dict:
    """``document`` as stored, once it holds together as tolerances (422 naming the limit
    that does not)."""
    try:
        return Tolerances.model_validate(document, strict=True).model_dump(
            mode="json", exclude_none=True
        )
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(["tolerances", *(str(p) for p in first["loc"])])
        raise Problem(422, f"{where}: {first['msg']}.") from exc


def check_owner(inspection: Inspection, actor: Actor, role: str, action: str) -> None:
    if role != "admin" and inspection.created_by != actor.id:
        raise Problem(
            403,
            f"Only the inspection's owner or an admin may {action} (inspection "
            f"{inspection.id} belongs to user {inspection.created_by}).",
        )


def _state(inspection: Inspection) -> dict:
    return {
        "title": inspection.title,
        "aircraft": inspection.aircraft,
        "serial": inspection.serial,
        "area": inspection.area,
        "tolerances": inspection.tolerances,
        "markers": inspection.markers,
        "status": inspection.status,
    }


def create(session: Session, *, data: InspectionCreate, actor: Actor) -> Inspection:
    inspection = Inspection(
        title=data.title,
        aircraft=data.aircraft,
        serial=data.serial,
        area=data.area,
        tolerances=data.tolerances.model_dump(mode="json", exclude_none=True),
        markers=[m.model_dump(mode="json") for m in data.markers],
        status=data.status,
        created_by=actor.id,
    )
    add_created(session, "inspection", inspection, actor.id)
    audit(
        session,
        actor,
        "create",
        entity="inspection",
        entity_id=inspection.id,
        inspection_id=inspection.id,
        after=_state(inspection),
    )
    return inspection


def update(
    session: Session, *, inspection_id: int, data: InspectionUpdate, actor: Actor, role: str
) -> Inspection:
    inspection = get(session, inspection_id=inspection_id)
    changes = data.model_dump(exclude_unset=True)  # null only where the schema allows it
    if "tolerances" in changes:
        sent = data.tolerances.changes() if data.tolerances is not None else None
        changes["tolerances"] = valid_tolerances(merge_tolerances(inspection.tolerances, sent))
    if "markers" in changes:
        changes["markers"] = [m.model_dump(mode="json") for m in data.markers]
    changes = {field: "" if value is None else value for field, value in changes.items()}
    before, after = changed_fields(_state(inspection), changes)
    if any(field in after for field in OWNER_ONLY_FIELDS):
        check_owner(inspection, actor, role, "change its tolerances")
    if "closed" in (before.get("status"), after.get("status")):
        check_owner(inspection, actor, role, "close or reopen it")
    for field, value in after.items():
        setattr(inspection, field, value)
    if "tolerances" in after and inspection.tolerance_set:  # no longer the set as applied
        inspection.tolerance_set = {**inspection.tolerance_set, "edited": True}
    session.flush()
    if after:
        record_change(  # moved markers change the scene's geometry (its ETag), the rest not
            session,
            entity="inspection",
            entity_id=inspection.id,
            op="geometry" if "markers" in after else "update",
            inspection_id=inspection.id,
            user_id=actor.id,
        )
        if "tolerances" in after:  # the findings follow, in this transaction
            after["rejudged_findings"] = rejudge_findings(session, inspection, user_id=actor.id)
        audit(
            session,
            actor,
            "update",
            entity="inspection",
            entity_id=inspection_id,
            inspection_id=inspection_id,
            before=before,
            after=after,
        )
    return inspection


def delete(session: Session, *, inspection_id: int, actor: Actor, role: str) -> None:
    """Move the inspection to the trash (its owner or an admin): hidden everywhere, its
    rows and files kept until an admin purges it."""
    inspection = get(session, inspection_id=inspection_id)
    check_owner(inspection, actor, role, "delete it")
    busy = session.scalar(
        select(
            exists().where(
                Job.inspection_id == inspection_id, Job.status.in_(("queued", "running"))
            )
        )
    )
    if busy:
        raise Problem(
            409, f"Inspection {inspection_id} has queued or running jobs; cancel them first."
        )
    inspection.deleted_at, inspection.deleted_by = utcnow(), actor.id
    record_change(
        session,
        entity="inspection",
        entity_id=inspection_id,
        op="delete",
        inspection_id=inspection_id,
        user_id=actor.id,
    )
    audit(
        session,
        actor,
        "delete",
        entity="inspection",
        entity_id=inspection_id,
        inspection_id=inspection_id,
        before={"deleted": False},
        after={"deleted": True},
    )


def trashed(session: Session, *, inspection_id: int) -> Inspection:
    inspection = session.get(Inspection, inspection_id)
    if inspection is None or inspection.deleted_at is None:
        raise not_found("inspection in the trash", inspection_id)
    return inspection


def restore(session: Session, *, inspection_id: int, actor: Actor) -> Inspection:
    """Take an inspection out of the trash, as it was."""
    inspection = trashed(session, inspection_id=inspection_id)
    inspection.deleted_at, inspection.deleted_by = None, None
    session.flush()
    record_update(session, "inspection", inspection, user_id=actor.id)
    audit(
        session,
        actor,
        "restore",
        entity="inspection",
        entity_id=inspection_id,
        inspection_id=inspection_id,
        before={"deleted": True},
        after={"deleted": False},
    )
    return inspection


def purge(session: Session, *, inspection_id: int, actor: Actor) -> None:
    """Delete a trashed inspection for good: its rows (artifacts, runs, jobs, defects,
    judgments) now, its files once the transaction committed (the caller's part)."""
    inspection = trashed(session, inspection_id=inspection_id)
    title = inspection.title
    session.delete(inspection)
    audit(
        session,
        actor,
        "purge",
        entity="inspection",
        entity_id=inspection_id,
        inspection_id=inspection_id,
        before={"deleted": True, "title": title},
    )


def follow_runs(session: Session, *, inspection_id: int) -> None:
    """The inspection's status follows its runs: ``processing`` while a job is unfinished,
    then ``review`` once a job has succeeded or there are findings to judge. A closed
    inspection stays closed; one whose jobs all failed stays ``processing``."""
    inspection = session.get(Inspection, inspection_id)
    if inspection is None or inspection.status == "closed" or inspection.deleted_at:
        return
    busy = session.scalar(
        select(exists().where(Job.inspection_id == inspection_id, Job.status.in_(UNFINISHED)))
    )
    done = session.scalar(
        select(
            exists().where(Defect.inspection_id == inspection_id)
            | exists().where(Job.inspection_id == inspection_id, Job.status == "succeeded")
        )
    )
    status = "processing" if busy else "review" if done else inspection.status
    if status != inspection.status:
        inspection.status = status
        record_change(
            session,
            entity="inspection",
            entity_id=inspection_id,
            op="update",
            inspection_id=inspection_id,
        )
