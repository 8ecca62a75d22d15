from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.orm import Session

from contract.tolerances import Limits, Tolerances, tolerances_of
from supervisor.deps import EDIT_ROLES, READ_ROLES, SESSION, CurrentUser, require
from supervisor.idempotency import create_once, digest_model
from supervisor.ids import IdPath
from supervisor.inspections.schemas import InspectionOut
from supervisor.models import Inspection, ToleranceSet
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, paginate
from supervisor.requests import JsonGuardRoute
from supervisor.tolerance_sets import service
from supervisor.tolerance_sets.schemas import (
    ApplySet,
    ToleranceSchemaOut,
    ToleranceSetCreate,
    ToleranceSetOut,
    ToleranceSetUpdate,
)

router = APIRouter(route_class=JsonGuardRoute, tags=["tolerances"])
readers = require(*READ_ROLES, action="read tolerances")
editors = require(*EDIT_ROLES, action="change tolerances")


@router.get("/tolerances/schema", response_model=ToleranceSchemaOut, response_model_by_alias=True)
def tolerance_schema(_: CurrentUser = Depends(readers)) -> ToleranceSchemaOut:
    """The tolerances document's JSON Schema and the default of every limit: what a form
    that edits an inspection's tolerances (or a set's) is drawn from."""
    return ToleranceSchemaOut(
        json_schema=Tolerances.model_json_schema(),
        defaults=tolerances_of(Limits()).model_dump(mode="json"),
    )


@router.get("/tolerance-sets", response_model=Page[ToleranceSetOut])
def list_sets(
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> Page[ToleranceSetOut]:
    """Named tolerance sets, in id order."""
    return paginate(session, select(ToleranceSet), cursor=cursor, limit=limit, item=ToleranceSetOut)


@router.post("/tolerance-sets", status_code=201, response_model=ToleranceSetOut)
def create_set(
    body: ToleranceSetCreate,
    request: Request,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> JSONResponse:
    """Name a set of acceptance limits to apply to inspections (inspectors and admins).
    A name in use: 409. The limits' rules are those of an inspection's (422)."""

    def create():  # noqa: ANN202
        made = service.create(session, data=body, actor=user)
        out = ToleranceSetOut.model_validate(made).model_dump(mode="json")
        return out, f"/api/v1/tolerance-sets/{made.id}"

    return create_once(
        request, session, user_id=user.id, body_digest=digest_model(body), create=create
    )


@router.get("/tolerance-sets/{set_id}", response_model=ToleranceSetOut)
def get_set(
    set_id: IdPath, session: Session = SESSION, _: CurrentUser = Depends(readers)
) -> ToleranceSet:
    return service.get(session, set_id=set_id)


@router.patch("/tolerance-sets/{set_id}", response_model=ToleranceSetOut)
def update_set(
    set_id: IdPath,
    body: ToleranceSetUpdate,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> ToleranceSet:
    """Rename it, describe it, or change its limits (only those named; null: a limit's
    default), which makes a new version; its maker or an admin (403). Inspections that
    applied an earlier version keep the limits they took."""
    return service.update(session, set_id=set_id, data=body, actor=user, role=user.role)


@router.delete("/tolerance-sets/{set_id}", status_code=204)
def delete_set(
    set_id: IdPath, session: Session = SESSION, user: CurrentUser = Depends(editors)
) -> Response:
    """Delete the set (its maker or an admin); inspections keep the limits they took."""
    service.delete(session, set_id=set_id, actor=user, role=user.role)
    return Response(status_code=204)


@router.post("/inspections/{inspection_id}/tolerance-set", response_model=InspectionOut)
def apply_set(
    inspection_id: IdPath,
    body: ApplySet,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> Inspection:
    """Give the inspection a set's limits (its owner or an admin, 403): the set's name and
    version are kept with it (`tolerance_set`) and in the audit log, and its findings are
    judged again by the new limits."""
    return service.apply(
        session, inspection_id=inspection_id, set_id=body.set_id, actor=user, role=user.role
    )
