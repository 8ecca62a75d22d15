from __future__ import annotations

from sqlalchemy import exists, select
from sqlalchemy.orm import Session

from supervisor.changes import add_created, record_change, record_update
from supervisor.inspections.schemas import InspectionCreate, InspectionUpdate
from supervisor.models import Defect, Inspection, Job
from supervisor.models.jobs import UNFINISHED
from supervisor.problems import Problem, not_found


def get(session: Session, *, inspection_id: int) -> Inspection:
    inspection = session.get(Inspection, inspection_id)
    if inspection is None:
        raise not_found("inspection", inspection_id)
    return inspection


def create(session: Session, *, data: InspectionCreate, user_id: int) -> Inspection:
    inspection = Inspection(
        title=data.title,
        aircraft=data.aircraft,
        serial=data.serial,
        area=data.area,
        tolerances=data.tolerances.model_dump(mode="json", exclude_none=True),
        markers=[m.model_dump(mode="json") for m in data.markers],
        status=data.status,
        created_by=user_id,
    )
    add_created(session, "inspection", inspection, user_id)
    return inspection


def update(
    session: Session, *, inspection_id: int, data: InspectionUpdate, user_id: int
) -> Inspection:
    inspection = get(session, inspection_id=inspection_id)
    changes = data.model_dump(exclude_unset=True)
    for field in ("title", "area", "status", "markers"):
        if field in changes and changes[field] is None:
            raise Problem(422, f"{field} cannot be null.")
    if "tolerances" in changes:
        changes["tolerances"] = (
            data.tolerances.model_dump(mode="json", exclude_none=True) if data.tolerances else {}
        )
    if "markers" in changes:
        changes["markers"] = [m.model_dump(mode="json") for m in data.markers]
    for field, value in changes.items():
        setattr(inspection, field, value if value is not None else "")
    session.flush()
    record_update(session, "inspection", inspection, user_id=user_id)
    return inspection


def delete(session: Session, *, inspection_id: int, user_id: int) -> None:
    inspection = get(session, inspection_id=inspection_id)
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
    session.delete(inspection)
    record_change(
        session,
        entity="inspection",
        entity_id=inspection_id,
        op="delete",
        inspection_id=inspection_id,
        user_id=user_id,
    )


def follow_runs(session: Session, *, inspection_id: int) -> None:
    """The inspection's status follows its runs: ``processing`` while a job is unfinished,
    then ``review`` once a job has succeeded or there are findings to judge. A closed
    inspection stays closed; one whose jobs all failed stays ``processing``."""
    inspection = session.get(Inspection, inspection_id)
    if inspection is None or inspection.status == "closed":
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
