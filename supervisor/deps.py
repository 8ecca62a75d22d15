"""Request dependencies: the database session and the signed-in user."""

from __future__ import annotations

import time
from collections.abc import AsyncIterator
from dataclasses import dataclass

from fastapi import Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from supervisor.auth.revocations import Revocations
from supervisor.auth.service import token_digest, user_for_token
from supervisor.db import commit
from supervisor.engine.runtime import Runtime
from supervisor.models._types import utcnow
from supervisor.models.users import ROLES, Role
from supervisor.problems import Problem

READ_ROLES: tuple[Role, ...] = ROLES
EDIT_ROLES: tuple[Role, ...] = ("admin", "inspector")
JUDGE_ROLES: tuple[Role, ...] = ("admin", "inspector", "device")
ADMIN_ROLES: tuple[Role, ...] = ("admin",)
DEVICE_WRITE_PATHS = ("/api/v1/sync/judgments", "/api/v1/auth/token")
"""The only writes a device token (a headset's) may make (sync, sign out); it reads
everything else."""

_bearer = HTTPBearer(auto_error=False, description="A token from POST /api/v1/auth/token.")


@dataclass(frozen=True)
class CurrentUser:
    id: int
    username: str
    role: str
    token_kind: str
    token_id: int


class TokenCache:
    """Recently checked tokens, so most requests need no database round trip to sign in.

    An entry lives ``ttl_s`` seconds (never past the token's own expiry) and only while
    the revocation stamp is the one read before the token was checked: a token revoked,
    or a user deactivated, through vista stops working at the next request in every API
    process; a change made by hand in the database, within ``ttl_s``.
    """

    def __init__(
        self, revocations: Revocations, ttl_s: float = 5.0, max_entries: int = 10_000
    ) -> None:
        self.revocations = revocations
        self.ttl_s = ttl_s
        self.max_entries = max_entries
        self._entries: dict[str, tuple[CurrentUser, float, int]] = {}

    def get(self, digest: str) -> CurrentUser | None:
        entry = self._entries.get(digest)
        if entry is None or entry[1] < time.monotonic():
            return None
        if entry[2] != self.revocations.stamp():
            return None
        return entry[0]

    def put(self, digest: str, user: CurrentUser, expires_in_s: float | None, stamp: int) -> None:
        """Keep ``user`` for ``digest``, checked when the revocation stamp was ``stamp``."""
        if len(self._entries) >= self.max_entries:
            self._entries.clear()
        lifetime = self.ttl_s if expires_in_s is None else min(self.ttl_s, expires_in_s)
        self._entries[digest] = (user, time.monotonic() + lifetime, stamp)


async def get_runtime(request: Request) -> Runtime:
    """The app's runtime. Async, as every dependency that does not block: FastAPI runs a
    plain ``def`` dependency on its thread pool, a hand-off each way per request."""
    return request.app.state.runtime


async def get_session(request: Request) -> AsyncIterator[Session]:
    """The request's session, and the one commit policy of the API.

    For a method that changes data it takes the write lock (SQLite) and commits when the
    endpoint has returned — before the response is sent (``SESSION`` gives it the
    function scope), so a failed commit is the response — then runs what the endpoint
    asked to follow the commit (``db.after_commit``). When the endpoint raises, nothing is
    committed. Creating it does no I/O, so only the commit and the close go to the thread
    pool.
    """
    write = request.method not in ("GET", "HEAD", "OPTIONS")
    session = request.app.state.runtime.db.session(write=write)
    try:
        yield session
        if write:
            await run_in_threadpool(commit, session)
    finally:
        await run_in_threadpool(session.close)


SESSION = Depends(get_session, scope="function")
"""The request's session (see ``get_session``): ``session: Session = SESSION``."""


def _look_up(request: Request, token: str) -> tuple[CurrentUser, float | None] | None:
    with request.app.state.runtime.db.read() as session:
        found = user_for_token(session, token)
    if found is None:
        return None
    user, api_token = found
    expires_in = (api_token.expires_at - utcnow()).total_seconds() if api_token.expires_at else None
    signed_in = CurrentUser(
        id=user.id,
        username=user.username,
        role=user.role,
        token_kind=api_token.kind,
        token_id=api_token.id,
    )
    return signed_in, expires_in


async def current_user(
    request: Request,
    credentials: HTTPAuthorizationCredentials | None = Depends(_bearer),
) -> CurrentUser:
    challenge = {"WWW-Authenticate": "Bearer"}
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise Problem(
            401, "Send a bearer token: 'Authorization: Bearer <token>'.", headers=challenge
        )
    cache: TokenCache = request.app.state.token_cache
    digest = token_digest(credentials.credentials)
    user = cache.get(digest)
    if user is not None:
        return _device_checked(request, user)
    stamp = cache.revocations.stamp()  # before the check: a revocation meanwhile shows
    found = await run_in_threadpool(_look_up, request, credentials.credentials)
    if found is None:
        raise Problem(
            401,
            "The token is unknown, expired or revoked, or its user is deactivated: sign in again.",
            headers=challenge,
        )
    user, expires_in = found
    cache.put(digest, user, expires_in, stamp)
    return _device_checked(request, user)


def _device_checked(request: Request, user: CurrentUser) -> CurrentUser:
    if (
        user.token_kind == "device"
        and request.method not in ("GET", "HEAD", "OPTIONS")
        and request.url.path not in DEVICE_WRITE_PATHS
    ):
        raise Problem(
            403,
            "A device token may only read and sync (POST /api/v1/sync/judgments); "
            "sign in as a person to change anything else.",
        )
    return user


def require(*roles: str, action: str):  # noqa: ANN201 - a FastAPI dependency
    async def dependency(user: CurrentUser = Depends(current_user)) -> CurrentUser:
        if user.role not in roles:
            raise Problem(403, f"A {user.role} may not {action}.")
        return user

    return dependency


def get_revocations(request: Request) -> Revocations:
    return request.app.state.token_cache.revocations
