from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response
from fastapi.responses import JSONResponse
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from supervisor.db import after_commit
from supervisor.deps import (
    ADMIN_ROLES,
    EDIT_ROLES,
    READ_ROLES,
    SESSION,
    CurrentUser,
    get_runtime,
    require,
)
from supervisor.engine.runtime import Runtime
from supervisor.idempotency import create_once, digest_model
from supervisor.ids import IdPath
from supervisor.inspections import service
from supervisor.inspections.schemas import (
    InspectionCreate,
    InspectionOut,
    InspectionUpdate,
    TrashedInspectionOut,
)
from supervisor.models import Inspection
from supervisor.models.inspections import AREA_SUGGESTIONS
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, paginate
from supervisor.requests import JsonGuardRoute

router = APIRouter(route_class=JsonGuardRoute, tags=["inspections"])
readers = require(*READ_ROLES, action="read inspections")
editors = require(*EDIT_ROLES, action="change inspections")
admins = require(*ADMIN_ROLES, action="manage the trash")


@router.post("/inspections", status_code=201, response_model=InspectionOut)
def create_inspection(
    body: InspectionCreate,
    request: Request,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> JSONResponse:
    """Create an inspection; you are its owner (`created_by`). Rules the schema cannot
    state (422): `tolerances.gap_mm.min` is below `max` (a side not given takes its
    default, 0.5 and 3.0 mm); each marker's `base_T_marker` is rigid (last row 0 0 0 1,
    rotation part orthonormal with determinant +1)."""

    def create():  # noqa: ANN202
        inspection = service.create(session, data=body, actor=user)
        out = InspectionOut.model_validate(inspection).model_dump(mode="json")
        return out, f"/api/v1/inspections/{inspection.id}"

    return create_once(
        request, session, user_id=user.id, body_digest=digest_model(body), create=create
    )


@router.get("/areas", response_model=list[str])
def areas(session: Session = SESSION, _: CurrentUser = Depends(readers)) -> list[str]:
    """What inspections' areas are called: those in use (most used first), then the usual
    ones — suggestions for a new inspection's free-text `area`."""
    used = session.execute(
        select(Inspection.area, func.count())
        .where(Inspection.deleted_at.is_(None))
        .group_by(Inspection.area)
        .order_by(func.count().desc(), Inspection.area)
    ).all()
    names = [area for area, _ in used]
    return names + [a for a in AREA_SUGGESTIONS if a not in names]


@router.get("/inspections", response_model=Page[InspectionOut])
def list_inspections(
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> Page[InspectionOut]:
    return paginate(
        session,
        select(Inspection).where(Inspection.deleted_at.is_(None)),
        cursor=cursor,
        limit=limit,
        item=InspectionOut,
    )


@router.get("/inspections/{inspection_id}", response_model=InspectionOut)
def get_inspection(
    inspection_id: IdPath,
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> Inspection:
    return service.get(session, inspection_id=inspection_id)


@router.patch("/inspections/{inspection_id}", response_model=InspectionOut)
def update_inspection(
    inspection_id: IdPath,
    body: InspectionUpdate,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> Inspection:
    """Change an inspection: only the fields given (`aircraft`, `serial` and `tolerances`
    may be null: empty). Its tolerances, and closing or reopening it, are for its owner
    (`created_by`) or an admin (403); every change is in the audit log. The rules of
    POST /inspections hold (422): `gap_mm.min` below `max`, rigid marker transforms."""
    return service.update(
        session, inspection_id=inspection_id, data=body, actor=user, role=user.role
    )


@router.delete("/inspections/{inspection_id}", status_code=204)
def delete_inspection(
    inspection_id: IdPath,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> Response:
    """Move an inspection to the trash (its owner or an admin; 409 while jobs are queued
    or running). It disappears from every list and sync (410); an admin can restore it
    with everything in it, or purge it for good."""
    service.delete(session, inspection_id=inspection_id, actor=user, role=user.role)
    return Response(status_code=204)


@router.get("/trash/inspections", response_model=Page[TrashedInspectionOut])
def list_trash(
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    _: CurrentUser = Depends(admins),
) -> Page[TrashedInspectionOut]:
    """Inspections in the trash, with who deleted them and when (admins)."""
    return paginate(
        session,
        select(Inspection).where(Inspection.deleted_at.is_not(None)),
        cursor=cursor,
        limit=limit,
        item=TrashedInspectionOut,
    )


@router.post("/trash/inspections/{inspection_id}/restore", response_model=InspectionOut)
def restore_inspection(
    inspection_id: IdPath,
    session: Session = SESSION,
    user: CurrentUser = Depends(admins),
) -> Inspection:
    """Take an inspection out of the trash with everything in it (admins)."""
    return service.restore(session, inspection_id=inspection_id, actor=user)


@router.delete("/trash/inspections/{inspection_id}", status_code=204)
def purge_inspection(
    inspection_id: IdPath,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(admins),
) -> Response:
    """Delete a trashed inspection for good: its artifacts, runs, jobs, defects, judgments
    and files (admins). Cannot be undone."""
    service.purge(session, inspection_id=inspection_id, actor=user)
    after_commit(session, lambda: runtime.storage.delete_inspection(inspection_id))
    return Response(status_code=204)
