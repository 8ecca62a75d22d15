"""Named tolerance sets: made once, applied to many inspections (their name and version
kept with each and in the audit log)."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from contract.tolerances import merge_tolerances
from supervisor.audit.service import Actor, audit
from supervisor.changes import record_update
from supervisor.defects.rejudge import rejudge_findings
from supervisor.inspections.service import check_owner, valid_tolerances
from supervisor.inspections.service import get as get_inspection
from supervisor.models import Inspection, ToleranceSet
from supervisor.problems import Problem, not_found
from supervisor.tolerance_sets.schemas import ToleranceSetCreate, ToleranceSetUpdate


def get(session: Session, *, set_id: int) -> ToleranceSet:
    found = session.get(ToleranceSet, set_id)
    if found is None:
        raise not_found("tolerance set", set_id)
    return found


def _unique_name(session: Session, name: str, but: int | None = None) -> None:
    taken = session.scalar(select(ToleranceSet.id).where(ToleranceSet.name == name))
    if taken is not None and taken != but:
        raise Problem(409, f"name: a tolerance set named {name!r} exists (id {taken}).")


def _state(found: ToleranceSet) -> dict:
    return {
        "name": found.name,
        "description": found.description,
        "tolerances": found.tolerances,
        "version": found.version,
    }


def create(session: Session, *, data: ToleranceSetCreate, actor: Actor) -> ToleranceSet:
    _unique_name(session, data.name)
    made = ToleranceSet(
        name=data.name,
        description=data.description,
        tolerances=data.tolerances.model_dump(mode="json", exclude_none=True),
        version=1,
        created_by=actor.id,
    )
    session.add(made)
    try:
        session.flush()
    except IntegrityError as exc:  # the same name, made at the same moment
        raise Problem(409, f"name: a tolerance set named {data.name!r} exists.") from exc
    audit(session, actor, "create", entity="tolerance_set", entity_id=made.id, after=_state(made))
    return made


def _check_maker(found: ToleranceSet, actor: Actor, role: str, action: str) -> None:
    if role != "admin" and found.created_by != actor.id:
        raise Problem(
            403,
            f"Only the tolerance set's maker or an admin may {action} it (set {found.id} "
            f"belongs to user {found.created_by}).",
        )


def update(
    session: Session, *, set_id: int, data: ToleranceSetUpdate, actor: Actor, role: str
) -> ToleranceSet:
    found = get(session, set_id=set_id)
    _check_maker(found, actor, role, "change")
    before = _state(found)
    sent = data.model_dump(exclude_unset=True)
    if sent.get("name") is not None:
        _unique_name(session, data.name, but=found.id)
        found.name = data.name
    if sent.get("description") is not None:
        found.description = data.description
    if "tolerances" in sent:
        changes = data.tolerances.changes() if data.tolerances is not None else None
        merged = valid_tolerances(merge_tolerances(found.tolerances, changes))
        if merged != found.tolerances:
            found.tolerances, found.version = merged, found.version + 1
    after = _state(found)
    if after != before:
        session.flush()
        audit(
            session,
            actor,
            "update",
            entity="tolerance_set",
            entity_id=found.id,
            before=before,
            after=after,
        )
    return found


def delete(session: Session, *, set_id: int, actor: Actor, role: str) -> None:
    """The set goes; inspections that applied it keep their limits and its name."""
    found = get(session, set_id=set_id)
    _check_maker(found, actor, role, "delete")
    audit(
        session, actor, "delete", entity="tolerance_set", entity_id=found.id, before=_state(found)
    )
    session.delete(found)


def apply(
    session: Session, *, inspection_id: int, set_id: int, actor: Actor, role: str
) -> Inspection:
    """The inspection takes the set's limits (its owner or an admin); its findings are
    judged again by them, in this transaction."""
    inspection = get_inspection(session, inspection_id=inspection_id)
    check_owner(inspection, actor, role, "change its tolerances")
    found = get(session, set_id=set_id)
    applied = {"id": found.id, "name": found.name, "version": found.version, "edited": False}
    before = {"tolerances": inspection.tolerances, "tolerance_set": inspection.tolerance_set}
    inspection.tolerances = dict(found.tolerances)
    inspection.tolerance_set = applied
    session.flush()
    record_update(session, "inspection", inspection, user_id=actor.id)
    rejudged = rejudge_findings(session, inspection, user_id=actor.id)
    audit(
        session,
        actor,
        "apply_tolerance_set",
        entity="inspection",
        entity_id=inspection.id,
        inspection_id=inspection.id,
        before=before,
        after={
            "tolerances": inspection.tolerances,
            "tolerance_set": applied,
            "rejudged_findings": rejudged,
        },
    )
    return inspection
