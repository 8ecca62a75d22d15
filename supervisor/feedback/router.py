from __future__ import annotations

from fastapi import APIRouter, Depends, Query
from sqlalchemy.orm import Session

from supervisor.deps import READ_ROLES, SESSION, CurrentUser, require
from supervisor.feedback import service
from supervisor.feedback.schemas import FeedbackOut
from supervisor.ids import IdQuery
from supervisor.inspections.service import get as get_inspection
from supervisor.requests import JsonGuardRoute

router = APIRouter(route_class=JsonGuardRoute, tags=["feedback"])
readers = require(*READ_ROLES, action="read the review feedback")


@router.get("/feedback", response_model=FeedbackOut)
def review_feedback(
    inspection: int | None = IdQuery("Only this inspection's findings (default: all)."),
    min_reviews: int = Query(
        3, ge=1, le=1000, description="Reviewed rows a group needs before a limit moves."
    ),
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> FeedbackOut:
    """Per defect type and limit: how many automatic findings reviewers confirmed or
    rejected, the rows within tolerance they judged defects, and the limit to use at the
    next inspection. With `inspection`, also its tolerances with the suggestions applied."""
    if inspection is not None:
        get_inspection(session, inspection_id=inspection)
    return service.feedback(session, inspection_id=inspection, min_reviews=min_reviews)
