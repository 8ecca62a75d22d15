"""Reading the audit log: every change of state, oldest first."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.audit.schemas import AuditEventOut
from supervisor.deps import READ_ROLES, SESSION, CurrentUser, require
from supervisor.ids import IdQuery
from supervisor.inspections.service import get as get_inspection
from supervisor.models import AuditEvent
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, paginate
from supervisor.problems import Problem
from supervisor.requests import JsonGuardRoute

router = APIRouter(route_class=JsonGuardRoute, tags=["audit"])
readers = require(*READ_ROLES, action="read the audit log")


@router.get("/audit", response_model=Page[AuditEventOut])
def list_events(
    inspection: int | None = IdQuery("Only changes in this inspection (required unless admin)."),
    entity: str | None = Query(
        None, max_length=32, description="inspection, defect, artifact, job, user or token."
    ),
    entity_id: int | None = IdQuery("Only changes of this entity (with `entity`)."),
    user: int | None = IdQuery("Only changes made by this user."),
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    me: CurrentUser = Depends(readers),
) -> Page[AuditEventOut]:
    """Who changed what, when, from what to what (judgments keep their own history: GET
    /defects/{id}/judgments). Admins read everything; others read one inspection's log."""
    if me.role != "admin":
        if inspection is None:
            raise Problem(403, "inspection: give one; only admins read the whole audit log.")
        get_inspection(session, inspection_id=inspection)
    return paginate(
        session,
        select(AuditEvent),
        equal={
            AuditEvent.inspection_id: inspection,
            AuditEvent.entity: entity,
            AuditEvent.entity_id: entity_id,
            AuditEvent.user_id: user,
        },
        cursor=cursor,
        limit=limit,
        item=AuditEventOut,
    )
