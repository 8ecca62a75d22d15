from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.db import after_commit
from supervisor.deps import EDIT_ROLES, READ_ROLES, SESSION, CurrentUser, get_runtime, require
from supervisor.engine.runtime import Runtime
from supervisor.idempotency import create_once, digest_model
from supervisor.ids import IdPath
from supervisor.inspections import service
from supervisor.inspections.schemas import InspectionCreate, InspectionOut, InspectionUpdate
from supervisor.models import Inspection
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, paginate

router = APIRouter(tags=["inspections"])
readers = require(*READ_ROLES, action="read inspections")
editors = require(*EDIT_ROLES, action="change inspections")


@router.post("/inspections", status_code=201, response_model=InspectionOut)
def create_inspection(
    body: InspectionCreate,
    request: Request,
    session: Session = SESSION,
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
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> Page[InspectionOut]:
    return paginate(
        session,
        select(Inspection),
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
    return service.update(session, inspection_id=inspection_id, data=body, user_id=user.id)


@router.delete("/inspections/{inspection_id}", status_code=204)
def delete_inspection(
    inspection_id: IdPath,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(editors),
) -> Response:
    """Delete an inspection with its artifacts, runs, jobs, defects and judgments."""
    service.delete(session, inspection_id=inspection_id, user_id=user.id)
    after_commit(session, lambda: runtime.storage.delete_inspection(inspection_id))
    return Response(status_code=204)
