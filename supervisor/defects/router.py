from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.defects import service
from supervisor.defects.schemas import (
    DefectCreate,
    DefectHistoryOut,
    DefectOut,
    DefectStatus,
    DefectType,
    DefectUpdate,
    NoteIn,
    Severity,
)
from supervisor.deps import EDIT_ROLES, READ_ROLES, SESSION, CurrentUser, require
from supervisor.idempotency import create_once, digest_model
from supervisor.ids import IdPath, IdQuery
from supervisor.inspections.service import live
from supervisor.models import Defect
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, paginate
from supervisor.requests import JsonGuardRoute

router = APIRouter(route_class=JsonGuardRoute, tags=["defects"])
readers = require(*READ_ROLES, action="read defects")
editors = require(*EDIT_ROLES, action="report or update defects")


@router.get("/defects", response_model=Page[DefectOut])
def list_defects(
    inspection: int | None = IdQuery("Only this inspection's defects."),
    run: int | None = IdQuery("Only defects found by this run."),
    type: DefectType | None = Query(None),
    status: DefectStatus | None = Query(None),
    severity: Severity | None = Query(
        None, description="`info` = measurements within tolerance (e.g. seams), kept for review."
    ),
    history: bool = Query(
        False,
        description="Also findings a later measurement ended (superseded, or not found "
        "again); without it only current ones are listed, unless `run` is given (a run's "
        "findings are all listed, ended or not).",
    ),
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> Page[DefectOut]:
    """Defects in id order, each with its reviewers' consensus; follow ``next_cursor``.
    Each physical defect is listed once: a finding measured again is its newest
    measurement's (`GET /defects/{id}/history` has the line)."""
    query = select(Defect).where(live(Defect.inspection_id))
    if not history and run is None:
        query = query.where(Defect.ended.is_(None))
    return paginate(
        session,
        query,
        equal={
            Defect.inspection_id: inspection,
            Defect.run_id: run,
            Defect.type: type,
            Defect.status: status,
            Defect.severity: severity,
        },
        cursor=cursor,
        limit=limit,
        item=DefectOut,
        out=lambda rows: service.defects_out(session, rows),
    )


@router.post("/defects", status_code=201, response_model=DefectOut)
def report_defect(
    body: DefectCreate,
    request: Request,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> JSONResponse:
    """Report a finding by hand (an inspector saw it; no job measured it). Rules the
    schema cannot state (422): `inspection_id` names an inspection not in the trash;
    `normal` is not the zero vector."""

    def create():  # noqa: ANN202
        defect = service.create(session, data=body, actor=user)
        out = service.defects_out(session, [defect])[0].model_dump(mode="json")
        return out, f"/api/v1/defects/{defect.id}"

    return create_once(
        request, session, user_id=user.id, body_digest=digest_model(body), create=create
    )


@router.get("/defects/{defect_id}", response_model=DefectOut)
def get_defect(
    defect_id: IdPath, session: Session = SESSION, _: CurrentUser = Depends(readers)
) -> DefectOut:
    return service.defects_out(session, [service.get(session, defect_id=defect_id)])[0]


@router.post("/defects/{defect_id}/notes", response_model=DefectOut)
def annotate_defect(
    defect_id: IdPath,
    body: NoteIn,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> DefectOut:
    """Add a note to a finding (inspectors and admins): who, what and when are kept with
    it (`notes`), sent to the headsets with the sync, and in the audit log."""
    defect = service.annotate(session, defect_id=defect_id, text=body.text, actor=user)
    return service.defects_out(session, [defect])[0]


@router.get("/defects/{defect_id}/history", response_model=DefectHistoryOut)
def defect_history(
    defect_id: IdPath, session: Session = SESSION, _: CurrentUser = Depends(readers)
) -> DefectHistoryOut:
    """The physical defect's line across measurements, oldest first: each run's finding,
    how it ended (superseded, not found again), and every judgment revision made along
    it with the run it was judged on."""
    return service.history(session, defect_id=defect_id)


@router.patch("/defects/{defect_id}", response_model=DefectOut)
def update_defect(
    defect_id: IdPath,
    body: DefectUpdate,
    session: Session = SESSION,
    user: CurrentUser = Depends(editors),
) -> DefectOut:
    """Move a defect through its workflow: open → resolved (repaired) or dismissed, or
    back to open. Dismissing needs a `reason` (not blank; 422), unless the defect is
    dismissed already (then nothing changes); a critical defect may be dismissed only by
    its inspection's owner or an admin. Who and why are kept (`status_by`,
    `status_reason`, the audit log)."""
    defect = service.set_status(
        session,
        defect_id=defect_id,
        status=body.status,
        reason=body.reason,
        actor=user,
        role=user.role,
    )
    return service.defects_out(session, [defect])[0]
