"""Request dependencies: the database session and the signed-in user."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from supervisor.auth.service import user_for_token
from supervisor.engine.runtime import Runtime
from supervisor.problems import Problem

READ_ROLES = ("admin", "inspector", "viewer", "device")
EDIT_ROLES = ("admin", "inspector")
JUDGE_ROLES = ("admin", "inspector", "device")
ADMIN_ROLES = ("admin",)

_bearer = HTTPBearer(auto_error=False, description="A token from POST /api/v1/auth/token.")


@dataclass(frozen=True)
class CurrentUser:
    id: int
    username: str
    role: str
    token_kind: str


def get_runtime(request: Request) -> Runtime:
    return request.app.state.runtime


def get_session(request: Request) -> Iterator[Session]:
    """A session that takes the write lock (SQLite) only for methods that change data."""
    write = request.method not in ("GET", "HEAD", "OPTIONS")
    with request.app.state.runtime.db.session(write=write) as session:
        yield session


def current_user(
    request: Request,
    credentials: HTTPAuthorizationCredentials | None = Depends(_bearer),
) -> CurrentUser:
    challenge = {"WWW-Authenticate": "Bearer"}
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise Problem(
            401, "Send a bearer token: 'Authorization: Bearer <token>'.", headers=challenge
        )
    with request.app.state.runtime.db.read() as session:
        found = user_for_token(session, credentials.credentials)
        if found is None:
            raise Problem(401, "The token is unknown, expired or revoked.", headers=challenge)
        user, token = found
        return CurrentUser(
            id=user.id, username=user.username, role=user.role, token_kind=token.kind
        )


def require(*roles: str, action: str):  # noqa: ANN201 - a FastAPI dependency
    def dependency(user: CurrentUser = Depends(current_user)) -> CurrentUser:
        if user.role not in roles:
            raise Problem(403, f"A {user.role} may not {action}.")
        return user

    return dependency
