from __future__ import annotations

from datetime import timedelta

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.deps import ADMIN_ROLES, SESSION, CurrentUser, require
from supervisor.idempotency import create_once, digest_model
from supervisor.ids import IdPath
from supervisor.models import User
from supervisor.models._types import utcnow
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, paginate
from supervisor.problems import not_found
from supervisor.users import service
from supervisor.users.schemas import TokenCreate, TokenCreated, UserCreate, UserOut

router = APIRouter(tags=["users"])
manage_users = require(*ADMIN_ROLES, action="manage users")


@router.post("/users", status_code=201, response_model=UserOut)
def create_user(
    body: UserCreate,
    request: Request,
    session: Session = SESSION,
    admin: CurrentUser = Depends(manage_users),
) -> JSONResponse:
    """Create a user (admins only). Device accounts have no password, only tokens."""

    def create():  # noqa: ANN202
        user = service.create_user(
            session, username=body.username, role=body.role, password=body.password
        )
        return UserOut.model_validate(user).model_dump(mode="json"), f"/api/v1/users/{user.id}"

    return create_once(
        request, session, user_id=admin.id, body_digest=digest_model(body), create=create
    )


@router.get("/users", response_model=Page[UserOut])
def list_users(
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    _: CurrentUser = Depends(manage_users),
) -> Page[UserOut]:
    return paginate(
        session,
        select(User),
        cursor=cursor,
        limit=limit,
        item=UserOut,
    )


@router.post("/users/{user_id}/tokens", status_code=201, response_model=TokenCreated)
def create_token(
    user_id: IdPath,
    body: TokenCreate,
    session: Session = SESSION,
    _: CurrentUser = Depends(manage_users),
) -> TokenCreated:
    """Issue an API token for a user, e.g. a headset's device token (admins only).

    The token is shown only in this response (it is stored hashed), so this POST does not
    replay on ``Idempotency-Key``: a lost response means issuing another token.
    """
    user = session.get(User, user_id)
    if user is None:
        raise not_found("user", user_id)
    token = service.create_token(
        session, user=user, name=body.name, kind=body.kind, ttl_hours=body.ttl_hours
    )
    expires = utcnow() + timedelta(hours=body.ttl_hours) if body.ttl_hours else None
    return TokenCreated(
        token=token, name=body.name, kind=body.kind, user_id=user.id, expires_at=expires
    )
