"""Passwords (argon2) and API tokens (random, stored as sha256)."""

from __future__ import annotations

import hashlib
import secrets
from datetime import timedelta

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.models import ApiToken, User
from supervisor.models._types import utcnow

TOKEN_PREFIX = "vst_"
_hasher = PasswordHasher()
# Verifying against a real hash when the user does not exist keeps timing uniform.
_DUMMY_HASH = _hasher.hash("vista-no-such-user")


def hash_password(password: str) -> str:
    return _hasher.hash(password)


def verify_password(password_hash: str | None, password: str) -> bool:
    try:
        return _hasher.verify(password_hash or _DUMMY_HASH, password) and bool(password_hash)
    except (VerificationError, InvalidHashError):
        return False


def token_digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def issue_token(
    session: Session, *, user: User, kind: str, name: str, ttl: timedelta | None
) -> str:
    """Create a token for ``user``; the plain token is returned once and never stored."""
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    session.add(
        ApiToken(
            user_id=user.id,
            name=name,
            kind=kind,
            token_sha256=token_digest(token),
            expires_at=utcnow() + ttl if ttl else None,
        )
    )
    return token


def user_for_token(session: Session, token: str) -> tuple[User, ApiToken] | None:
    row = session.execute(
        select(User, ApiToken)
        .join(ApiToken, ApiToken.user_id == User.id)
        .where(ApiToken.token_sha256 == token_digest(token))
    ).first()
    if row is None:
        return None
    user, api_token = row
    if api_token.revoked or not user.active:
        return None
    if api_token.expires_at is not None and api_token.expires_at <= utcnow():
        return None
    return user, api_token


def authenticate(session: Session, *, username: str, password: str) -> User | None:
    user = session.scalar(select(User).where(User.username == username))
    if not verify_password(user.password_hash if user else None, password):
        return None
    return user if user and user.active else None
