"""Sign-in, sign-out and the signed-in user's own account."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from datetime import datetime
from typing import TypeVar

from fastapi import APIRouter, Depends, Request, Response
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select, update

from supervisor.audit.service import Operator
from supervisor.auth import service
from supervisor.auth.limits import REFUSAL_DELAY_S, SignInGuard, TooManySignIns
from supervisor.auth.schemas import MeOut, TokenOut, TokenRequest
from supervisor.deps import (
    READ_ROLES,
    CurrentUser,
    current_user,
    get_revocations,
    get_runtime,
    require,
)
from supervisor.engine.runtime import Runtime
from supervisor.models import User
from supervisor.models._types import utcnow
from supervisor.problems import Problem
from supervisor.requests import JsonGuardRoute
from supervisor.users import service as users
from supervisor.users.schemas import PasswordChange

router = APIRouter(route_class=JsonGuardRoute, tags=["auth"])
signed_in = require(*READ_ROLES, action="sign out")
NO_STORE = {"Cache-Control": "no-store", "Pragma": "no-cache"}
T = TypeVar("T")


def _guard(request: Request, runtime: Runtime) -> SignInGuard:
    state = request.app.state
    if getattr(state, "sign_in_guard", None) is None:
        settings = runtime.settings
        state.sign_in_guard = SignInGuard(
            per_account=settings.sign_in_per_account_per_min,
            per_address=settings.sign_in_per_address_per_min,
            concurrency=settings.sign_in_concurrency,
            slot_folder=settings.data_dir / "sign-in-slots",
        )
    return state.sign_in_guard


async def _checked(guard: SignInGuard, check: Callable[[], T]) -> T:
    """``check`` (an argon2 verification) in a thread, holding a password-check slot."""
    fd = await guard.slot()
    try:
        return await run_in_threadpool(check)
    finally:
        guard.release(fd)


@router.post(
    "/auth/token",
    response_model=TokenOut,
    responses={429: {"description": "Too many sign-ins: wait `Retry-After` seconds."}},
)
async def sign_in(
    body: TokenRequest, request: Request, runtime: Runtime = Depends(get_runtime)
) -> Response:
    """Exchange a username and password for a bearer token (a `session` token that expires
    after VISTA_TOKEN_TTL_HOURS). Failed sign-ins per account and sign-ins per address are
    limited per minute (429 with `Retry-After`)."""
    guard = _guard(request, runtime)
    address = request.client.host if request.client else "unknown"
    try:
        guard.admit(username=body.username, address=address)
    except TooManySignIns as exc:
        await asyncio.sleep(REFUSAL_DELAY_S)  # idle: a client ignoring Retry-After waits too
        raise Problem(
            429,
            f"{exc.reason}: try again in {exc.retry_after_s} s.",
            headers={"Retry-After": str(exc.retry_after_s)},
        ) from exc
    user = await run_in_threadpool(_account, runtime, body.username)
    hash_ = user.password_hash if user is not None else None
    if not await _checked(guard, lambda: service.verify_password(hash_, body.password)):
        guard.failed(body.username)
        raise Problem(401, "Unknown username or wrong password.")
    if user is None or not user.active:  # a right password of a deactivated account
        raise Problem(401, "Unknown username or wrong password.")
    rehashed = None
    if service.needs_rehash(hash_):  # made with older argon2 parameters
        rehashed = await _checked(guard, lambda: service.hash_password(body.password))
    token, expires_at = await run_in_threadpool(_issue, runtime, user, rehashed)
    out = TokenOut(access_token=token, expires_at=expires_at)
    return Response(out.model_dump_json(), media_type="application/json", headers=NO_STORE)


def _account(runtime: Runtime, username: str) -> User | None:
    with runtime.db.read() as session:
        return session.scalar(select(User).where(User.username == username))


def _issue(runtime: Runtime, user: User, rehashed: str | None) -> tuple[str, datetime]:
    """A sign-in token (and the password's new hash, if re-made), in a short write
    transaction (never around the password check: on SQLite that would hold every writer
    back for half a second)."""
    ttl = users.default_ttl("session", runtime.settings)
    with runtime.db.write() as session:
        if rehashed is not None:
            session.execute(update(User).where(User.id == user.id).values(password_hash=rehashed))
        signed_in_as = Operator(user.id, user.username)  # the sign-in is in the audit log
        token = users.create_token(
            session, user=user, name="sign-in", kind="session", ttl=ttl, actor=signed_in_as
        )
    return token, utcnow() + ttl


@router.delete("/auth/token", status_code=204)
def sign_out(
    request: Request,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(signed_in),
) -> Response:
    """Sign out: revoke the token this request is made with (any kind); it stops working
    at once in every API process."""
    with runtime.db.write() as session:
        users.revoke(session, actor=user, reason="signed out", token_id=user.token_id)
    get_revocations(request).bump()
    return Response(status_code=204)


@router.get("/me", response_model=MeOut)
def me(user: CurrentUser = Depends(current_user)) -> MeOut:
    """Who the bearer token belongs to."""
    return MeOut(id=user.id, username=user.username, role=user.role, token_kind=user.token_kind)


@router.put("/me/password", status_code=204)
async def change_my_password(
    body: PasswordChange,
    request: Request,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(signed_in),
) -> Response:
    """Change your password (give the current one). Your other sign-in tokens are revoked;
    CLI and device tokens keep working (revoke them with POST /tokens/revoke)."""
    guard = _guard(request, runtime)
    changed = await _checked(guard, lambda: _change_password(runtime, user, body))
    if not changed:
        raise Problem(403, "current_password: that is not your current password.")
    get_revocations(request).bump()
    return Response(status_code=204)


def _change_password(runtime: Runtime, user: CurrentUser, body: PasswordChange) -> bool:
    """Both argon2 steps outside any transaction; then one short write."""
    with runtime.db.read() as session:
        current = users.get_user(session, user.id).password_hash
    if not service.verify_password(current, body.current_password):
        return False
    new_hash = service.hash_password(body.new_password)
    with runtime.db.write() as session:
        account = users.get_user(session, user.id)
        users.change_user(session, account, actor=user, password_hash=new_hash)
        users.revoke(
            session,
            actor=user,
            reason="password changed",
            user_id=user.id,
            kind="session",
            except_id=user.token_id,
        )
    return True
