from __future__ import annotations

from datetime import timedelta

from fastapi import APIRouter, Depends
from sqlalchemy.orm import Session

from supervisor.auth import service
from supervisor.auth.schemas import MeOut, TokenOut, TokenRequest
from supervisor.deps import SESSION, CurrentUser, current_user, get_runtime
from supervisor.engine.runtime import Runtime
from supervisor.models._types import utcnow
from supervisor.problems import Problem

router = APIRouter(tags=["auth"])


@router.post("/auth/token", response_model=TokenOut)
def sign_in(
    body: TokenRequest,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
) -> TokenOut:
    """Exchange a username and password for a bearer token."""
    user = service.authenticate(session, username=body.username, password=body.password)
    if user is None:
        raise Problem(401, "Unknown username or wrong password.")
    ttl = timedelta(hours=runtime.settings.token_ttl_hours)
    token = service.issue_token(session, user=user, kind="session", name="sign-in", ttl=ttl)
    return TokenOut(access_token=token, expires_at=utcnow() + ttl)


@router.get("/me", response_model=MeOut)
def me(user: CurrentUser = Depends(current_user)) -> MeOut:
    """Who the bearer token belongs to."""
    return MeOut(id=user.id, username=user.username, role=user.role, token_kind=user.token_kind)
