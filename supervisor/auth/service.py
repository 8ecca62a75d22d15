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
# argon2id with 64 MiB and 3 passes (RFC 9106's second recommendation) on ONE lane: the
# library runs a thread per lane, and argon2-cffi's default of four lanes would take every
# core of a small server for each sign-in, whatever the API bounds. Hashes made with other
# parameters still verify and are re-made at the next successful sign-in.
_hasher = PasswordHasher(time_cost=3, memory_cost=65536, parallelism=1)
# Verifying against a real hash when the user does not exist keeps timing uniform.
_DUMMY_HASH = _hasher.hash("vista-no-such-user")


def hash_password(password: str) -> str:
    return _hasher.hash(password)


def needs_rehash(password_hash: str) -> bool:
    return _hasher.check_needs_rehash(password_hash)


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
