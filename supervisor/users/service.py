from __future__ import annotations

from datetime import timedelta

from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.auth.service import hash_password, issue_token
from supervisor.models import User
from supervisor.problems import Problem


def create_user(session: Session, *, username: str, role: str, password: str | None) -> User:
    if session.scalar(select(User.id).where(User.username == username)) is not None:
        raise Problem(409, f"A user named {username!r} already exists.")
    user = User(
        username=username,
        role=role,
        password_hash=hash_password(password) if password else None,
        active=True,
    )
    session.add(user)
    session.flush()
    return user


def create_token(
    session: Session, *, user: User, name: str, kind: str, ttl_hours: float | None
) -> str:
    ttl = timedelta(hours=ttl_hours) if ttl_hours else None
    return issue_token(session, user=user, kind=kind, name=name, ttl=ttl)
