from __future__ import annotations

from fastapi import APIRouter, Depends, Response
from fastapi.concurrency import run_in_threadpool
from sqlalchemy.orm import Session

from supervisor.deps import (
    JUDGE_ROLES,
    READ_ROLES,
    SESSION,
    CurrentUser,
    get_runtime,
    require,
)
from supervisor.engine.runtime import Runtime
from supervisor.ids import IdPath
from supervisor.judgments import service
from supervisor.judgments.schemas import DefectJudgmentsOut, JudgmentIn, MyJudgmentOut
from supervisor.requests import JsonGuardRoute

router = APIRouter(route_class=JsonGuardRoute, tags=["judgments"])
readers = require(*READ_ROLES, action="read judgments")
judges = require(*JUDGE_ROLES, action="judge defects")


@router.put("/defects/{defect_id}/judgments/me", response_model=MyJudgmentOut)
async def put_my_judgment(
    defect_id: IdPath,
    body: JudgmentIn,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(judges),
) -> Response:
    """Set your judgment of a defect. Each change is a new revision; repeating the same
    judgment changes nothing. Nobody can write another user's judgment. `new_type` is
    given exactly when the verdict is `reclassified`, and must differ from the defect's
    type (422)."""
    judgment, consensus = await run_in_threadpool(
        service.put_mine, runtime.db, defect_id=defect_id, user_id=user.id, data=body
    )
    out = MyJudgmentOut(judgment=service.judgment_out(judgment, user.username), consensus=consensus)
    # Built by the model above already: skip FastAPI's second validation (hot path).
    return Response(out.model_dump_json(), media_type="application/json")


@router.get("/defects/{defect_id}/judgments", response_model=DefectJudgmentsOut)
def list_judgments(
    defect_id: IdPath, session: Session = SESSION, _: CurrentUser = Depends(readers)
) -> DefectJudgmentsOut:
    """Every user's current judgment with its full history, and the consensus."""
    return service.all_for_defect(session, defect_id=defect_id)
