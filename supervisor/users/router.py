"""Users and tokens: admins manage everyone; each user lists and revokes their own."""

from __future__ import annotations

from datetime import timedelta

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.auth.service import hash_password
from supervisor.db import after_commit
from supervisor.deps import (
    ADMIN_ROLES,
    READ_ROLES,
    SESSION,
    CurrentUser,
    get_revocations,
    get_runtime,
    require,
)
from supervisor.engine.runtime import Runtime
from supervisor.idempotency import create_once, digest_model
from supervisor.ids import IdPath, IdQuery
from supervisor.models import ApiToken, User
from supervisor.models._types import utcnow
from supervisor.models.users import TokenKind
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, paginate
from supervisor.problems import Problem, not_found
from supervisor.requests import JsonGuardRoute
from supervisor.users import service
from supervisor.users.schemas import (
    RevokedOut,
    RevokeRequest,
    TokenCreate,
    TokenCreated,
    TokenInfo,
    UserCreate,
    UserOut,
    UserUpdate,
)

router = APIRouter(route_class=JsonGuardRoute, tags=["users"])
manage_users = require(*ADMIN_ROLES, action="manage users")
signed_in = require(*READ_ROLES, action="manage tokens")


def _hashed(password: str | None) -> str | None:
    """argon2id of ``password``, before the request's first statement: the write lock
    (SQLite) is taken there, and no writer should wait half a second on a hash."""
    return hash_password(password) if password is not None else None


def revoked_after_commit(session: Session, request: Request) -> None:
    """Every API process checks its cached tokens again once this transaction committed."""
    after_commit(session, get_revocations(request).bump)


@router.post("/users", status_code=201, response_model=UserOut)
def create_user(
    body: UserCreate,
    request: Request,
    session: Session = SESSION,
    admin: CurrentUser = Depends(manage_users),
) -> JSONResponse:
    """Create a user (admins only). A person's account (admin, inspector, viewer) needs a
    `password`; a device account has none and signs in with tokens only. 409 when the
    username is taken."""

    password_hash = _hashed(body.password)

    def create():  # noqa: ANN202
        user = service.create_user(
            session,
            username=body.username,
            role=body.role,
            password_hash=password_hash,
            actor=admin,
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
    return paginate(session, select(User), cursor=cursor, limit=limit, item=UserOut)


@router.get("/users/{user_id}", response_model=UserOut)
def get_user(
    user_id: IdPath, session: Session = SESSION, _: CurrentUser = Depends(manage_users)
) -> User:
    return service.get_user(session, user_id)


@router.patch("/users/{user_id}", response_model=UserOut)
def update_user(
    user_id: IdPath,
    body: UserUpdate,
    request: Request,
    session: Session = SESSION,
    admin: CurrentUser = Depends(manage_users),
) -> User:
    """Deactivate (`active: false`: their tokens stop working at once), reactivate, change
    the role or set the password of a user (admins); a field left out or null is kept.
    The last active admin stays one (409); a device account has no password (422)."""
    password_hash = _hashed(body.password)
    user = service.get_user(session, user_id)
    service.change_user(
        session,
        user,
        actor=admin,
        active=body.active,
        role=body.role,
        password_hash=password_hash,
    )
    revoked_after_commit(session, request)
    return user


@router.post("/users/{user_id}/tokens", status_code=201, response_model=TokenCreated)
def create_token(
    user_id: IdPath,
    body: TokenCreate,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
    admin: CurrentUser = Depends(manage_users),
) -> TokenCreated:
    """Issue an API token for a user, e.g. a headset's device token (admins only; 409 for a
    deactivated user). Every token expires: `ttl_hours`, or the default of its kind.

    The token is shown only in this response (it is stored hashed), so this POST does not
    replay on ``Idempotency-Key``: a lost response means issuing another token.
    """
    user = service.get_user(session, user_id)
    ttl = (
        timedelta(hours=body.ttl_hours)
        if body.ttl_hours
        else service.default_ttl(body.kind, runtime.settings)
    )
    token = service.create_token(
        session, user=user, name=body.name, kind=body.kind, ttl=ttl, actor=admin
    )
    return TokenCreated(
        token=token,
        name=body.name,
        kind=body.kind,
        user_id=user.id,
        expires_at=utcnow() + ttl,
    )


@router.get("/tokens", response_model=Page[TokenInfo])
def list_tokens(
    user: int | None = IdQuery("Only this user's tokens (others than yours: admins)."),
    kind: TokenKind | None = Query(None),
    name: str | None = Query(None, max_length=128, description="Only tokens of this name."),
    include_ended: bool = Query(False, description="Also revoked and expired tokens."),
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    me: CurrentUser = Depends(signed_in),
) -> Page[TokenInfo]:
    """Tokens that still work (never the token itself): yours, or anyone's for an admin
    (a non-admin's `user` can only be themself: 403 otherwise)."""
    if me.role != "admin":
        if user not in (None, me.id):
            raise Problem(403, "Only admins may list another user's tokens.")
        user = me.id
    query = service.tokens_query(user_id=user, kind=kind, name=name, include_ended=include_ended)

    def out(tokens: list[ApiToken]) -> list[TokenInfo]:
        names = service.usernames(session, {token.user_id for token in tokens})
        return [_token_info(token, names[token.user_id], me) for token in tokens]

    return paginate(session, query, cursor=cursor, limit=limit, item=TokenInfo, out=out)


def _token_info(token: ApiToken, username: str, me: CurrentUser) -> TokenInfo:
    return TokenInfo(
        id=token.id,
        user_id=token.user_id,
        username=username,
        name=token.name,
        kind=token.kind,
        created_at=token.created_at,
        expires_at=token.expires_at,
        revoked=token.revoked,
        revoked_at=token.revoked_at,
        current=token.id == me.token_id,
    )


@router.delete("/tokens/{token_id}", status_code=204)
def revoke_token(
    token_id: IdPath,
    request: Request,
    session: Session = SESSION,
    me: CurrentUser = Depends(signed_in),
) -> Response:
    """Revoke one token (yours, or anyone's for an admin: another user's token is not
    found for a non-admin); it stops working at the next request. Revoking a revoked token
    changes nothing."""
    token = session.get(ApiToken, token_id)
    if token is None or (me.role != "admin" and token.user_id != me.id):
        raise not_found("token", token_id)
    service.revoke(session, actor=me, token_id=token_id)
    revoked_after_commit(session, request)
    return Response(status_code=204)


@router.post("/tokens/revoke", response_model=RevokedOut)
def revoke_tokens(
    body: RevokeRequest,
    request: Request,
    session: Session = SESSION,
    me: CurrentUser = Depends(signed_in),
) -> RevokedOut:
    """Revoke every token of a user (`user_id`: yours, or anyone's for an admin) or every
    device token of a name (`device`: a lost headset; admins). Give exactly one of the
    two."""
    if me.role != "admin" and (body.device is not None or body.user_id != me.id):
        raise Problem(403, "Only admins may revoke another user's or a device's tokens.")
    if body.user_id is not None:
        service.get_user(session, body.user_id)
        ids = service.revoke(session, actor=me, reason=body.reason, user_id=body.user_id)
    else:
        ids = service.revoke(session, actor=me, reason=body.reason, kind="device", name=body.device)
    revoked_after_commit(session, request)
    return RevokedOut(revoked=ids)
