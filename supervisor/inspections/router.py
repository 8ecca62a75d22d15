from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.deps import EDIT_ROLES, READ_ROLES, CurrentUser, get_runtime, get_session, require
from supervisor.engine.runtime import Runtime
from supervisor.idempotency import create_once, digest_model
from supervisor.ids import IdPath
from supervisor.inspections import service
from supervisor.inspections.schemas import InspectionCreate, InspectionOut, InspectionUpdate
from supervisor.models import Inspection
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, decode_cursor, next_cursor

router = APIRouter(tags=["inspections"])
readers = require(*READ_ROLES, action="read inspections")
editors = require(*EDIT_ROLES, action="change inspections")


@router.post("/inspections", status_code=201, response_model=InspectionOut)
def create_inspection(
    body: InspectionCreate,
    request: Request,
    session: Session = Depends(get_session),
    user: CurrentUser = Depends(editors),
) -> JSONResponse:
    def create():  # noqa: ANN202
        inspection = service.create(session, data=body, user_id=user.id)
        out = InspectionOut.model_validate(inspection).model_dump(mode="json")
        return out, f"/api/v1/inspections/{inspection.id}"

    return create_once(
        request, session, user_id=user.id, body_digest=digest_model(body), create=create
    )


@router.get("/inspections", response_model=Page[InspectionOut])
def list_inspections(
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = Depends(get_session),
    _: CurrentUser = Depends(readers),
) -> Page[InspectionOut]:
    rows = session.scalars(
        select(Inspection)
        .where(Inspection.id > decode_cursor(cursor))
        .order_by(Inspection.id)
        .limit(limit + 1)
    ).all()
    return Page[InspectionOut](
        items=[InspectionOut.model_validate(i) for i in rows[:limit]],
        next_cursor=next_cursor(rows, limit),
    )


@router.get("/inspections/{inspection_id}", response_model=InspectionOut)
def get_inspection(
    inspection_id: IdPath,
    session: Session = Depends(get_session),
    _: CurrentUser = Depends(readers),
) -> Inspection:
    return service.get(session, inspection_id=inspection_id)


@router.patch("/inspections/{inspection_id}", response_model=InspectionOut)
def update_inspection(
    inspection_id: IdPath,
    body: InspectionUpdate,
    session: Session = Depends(get_session),
    user: CurrentUser = Depends(editors),
) -> Inspection:
    inspection = service.update(session, inspection_id=inspection_id, data=body, user_id=user.id)
    session.commit()
    return inspection


@router.delete("/inspections/{inspection_id}", status_code=204)
def delete_inspection(
    inspection_id: IdPath,
    session: Session = Depends(get_session),
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(editors),
) -> Response:
    """Delete an inspection with its artifacts, runs, jobs, defects and judgments."""
    service.delete(session, inspection_id=inspection_id, user_id=user.id)
    session.commit()
    runtime.storage.delete_inspection(inspection_id)
    return Response(status_code=204)
