"""Users and their tokens: create, list, revoke, deactivate, set passwords.

Every change is in the audit log. Revoking a token, deactivating a user or changing a
password ends the affected tokens at the next request (``auth.revocations``): the caller
bumps the revocation stamp once its transaction committed.
"""

from __future__ import annotations

from datetime import timedelta

from sqlalchemy import Select, func, select, update
from sqlalchemy.orm import Session

from supervisor.audit.service import COMMAND_LINE, Actor, audit
from supervisor.auth.service import issue_token
from supervisor.models import ApiToken, User
from supervisor.models._types import utcnow
from supervisor.problems import Problem, not_found
from supervisor.settings import Settings


def default_ttl(kind: str, settings: Settings) -> timedelta:
    """Every token expires: a sign-in after hours, a CLI token or a headset's after days."""
    if kind == "session":
        return timedelta(hours=settings.token_ttl_hours)
    days = settings.device_token_ttl_days if kind == "device" else settings.cli_token_ttl_days
    return timedelta(days=days)


def get_user(session: Session, user_id: int) -> User:
    user = session.get(User, user_id)
    if user is None:
        raise not_found("user", user_id)
    return user


def by_name(session: Session, username: str) -> User:
    user = session.scalar(select(User).where(User.username == username))
    if user is None:
        raise Problem(404, f"There is no user named {username!r}.")
    return user


def name_taken(session: Session, username: str) -> bool:
    return session.scalar(select(User.id).where(User.username == username)) is not None


def create_user(
    session: Session,
    *,
    username: str,
    role: str,
    password_hash: str | None,
    actor: Actor = COMMAND_LINE,
) -> User:
    """A new user; ``password_hash`` from ``auth.service.hash_password``, computed before
    the transaction (argon2 takes half a second: no write lock may wait on it)."""
    if name_taken(session, username):
        raise Problem(409, f"A user named {username!r} already exists.")
    user = User(username=username, role=role, password_hash=password_hash, active=True)
    session.add(user)
    session.flush()
    audit(session, actor, "create", entity="user", entity_id=user.id, after=_user_state(user))
    return user


def _user_state(user: User) -> dict:
    return {"username": user.username, "role": user.role, "active": user.active}


def create_token(
    session: Session,
    *,
    user: User,
    name: str,
    kind: str,
    ttl: timedelta,
    actor: Actor = COMMAND_LINE,
) -> str:
    """A new token for an active user; the plain token is returned once."""
    if not user.active:
        raise Problem(409, f"User {user.username!r} is deactivated; reactivate them first.")
    token = issue_token(session, user=user, kind=kind, name=name, ttl=ttl)
    session.flush()
    token_id = session.scalar(select(func.max(ApiToken.id)).where(ApiToken.user_id == user.id))
    audit(
        session,
        actor,
        "issue",
        entity="token",
        entity_id=token_id,
        after={"user": user.username, "name": name, "kind": kind, "ttl_s": ttl.total_seconds()},
    )
    return token


def usernames(session: Session, user_ids: set[int]) -> dict[int, str]:
    rows = session.execute(select(User.id, User.username).where(User.id.in_(user_ids)))
    return {user_id: username for user_id, username in rows}


def tokens_query(
    *,
    user_id: int | None = None,
    kind: str | None = None,
    name: str | None = None,
    include_ended: bool = False,
) -> Select:
    """Tokens in id order; without ``include_ended`` only those that still work."""
    query = select(ApiToken)
    if user_id is not None:
        query = query.where(ApiToken.user_id == user_id)
    if kind is not None:
        query = query.where(ApiToken.kind == kind)
    if name is not None:
        query = query.where(ApiToken.name == name)
    if not include_ended:
        query = query.where(ApiToken.revoked.is_(False), ApiToken.expires_at > utcnow())
    return query


def revoke(session: Session, *, actor: Actor, reason: str = "", **where: object) -> list[int]:
    """Revoke the working tokens matching ``where`` (``token_id``, ``user_id``, ``kind``,
    ``name``, ``except_id``); returns their ids (none: nothing matched)."""
    query = update(ApiToken).where(ApiToken.revoked.is_(False))
    columns = {
        "token_id": ApiToken.id,
        "user_id": ApiToken.user_id,
        "kind": ApiToken.kind,
        "name": ApiToken.name,
    }
    for key, value in where.items():
        if key == "except_id":
            query = query.where(ApiToken.id != value)
        elif value is not None:
            query = query.where(columns[key] == value)
    ids = list(
        session.scalars(query.values(revoked=True, revoked_at=utcnow()).returning(ApiToken.id))
    )
    for token_id in ids:
        audit(
            session,
            actor,
            "revoke",
            entity="token",
            entity_id=token_id,
            before={"revoked": False},
            after={"revoked": True},
            reason=reason,
        )
    return ids


def _other_active_admins(session: Session, user: User) -> int:
    return session.scalar(
        select(func.count()).where(User.role == "admin", User.active.is_(True), User.id != user.id)
    )


def change_user(
    session: Session,
    user: User,
    *,
    actor: Actor,
    active: bool | None = None,
    role: str | None = None,
    password_hash: str | None = None,
) -> User:
    """Deactivate or reactivate a user, change their role or set their password. A
    deactivated user's tokens stop working (and stay stopped when reactivated: issue new
    ones); the last active admin cannot be deactivated or demoted. ``password_hash`` as
    for ``create_user``."""
    losing_admin = user.role == "admin" and (active is False or (role and role != "admin"))
    if losing_admin and user.active and _other_active_admins(session, user) == 0:
        raise Problem(409, f"{user.username!r} is the last active admin; make another admin first.")
    if password_hash is not None and user.role == "device":
        raise Problem(422, "password: device accounts sign in with tokens only.")
    before = _user_state(user)
    if active is not None:
        user.active = active
    if role is not None:
        user.role = role
    after = _user_state(user)
    changed_before = {k: v for k, v in before.items() if after[k] != v}
    changed_after = {k: after[k] for k in changed_before}
    if password_hash is not None:
        user.password_hash = password_hash
        changed_before["password"], changed_after["password"] = "(old)", "(new)"
    if active is False:
        revoke(session, actor=actor, reason="user deactivated", user_id=user.id)
    if changed_after:
        audit(
            session,
            actor,
            "update",
            entity="user",
            entity_id=user.id,
            before=changed_before,
            after=changed_after,
        )
    session.flush()
    return user
