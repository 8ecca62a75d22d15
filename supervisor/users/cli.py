"""``vista user …``: manage users and tokens on the server's machine (the database
directly; every change is in the audit log as made at the command line)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from datetime import timedelta

import typer
from sqlalchemy.orm import Session

from contract.cli import fail

app = typer.Typer(help="Manage users and their tokens.", no_args_is_help=True)
ROLE_HELP = "admin, inspector, viewer or device."


@contextmanager
def _database(*, revokes: bool = False) -> Iterator[Session]:
    """A write session on the configured database; a refusal is a one-line error. With
    ``revokes``, every API process re-checks its cached tokens once it committed."""
    from supervisor.auth.revocations import Revocations
    from supervisor.db import Database
    from supervisor.problems import Problem
    from supervisor.settings import get_settings

    settings = get_settings()
    db = Database(settings.resolved_database_url, sqlite_synchronous=settings.sqlite_synchronous)
    try:
        with db.write() as session:
            yield session
    except Problem as exc:
        fail(exc.detail)
    finally:
        db.dispose()
    if revokes:
        Revocations(settings.resolved_artifact_dir).bump()


def _ask_password() -> str:
    """A new password, asked twice; returned hashed (argon2id)."""
    from supervisor.auth.service import hash_password

    secret = typer.prompt("password", hide_input=True, confirmation_prompt=True)
    if len(secret) < 8:
        fail("the password needs at least 8 characters")
    return hash_password(secret)


def _ttl(kind: str, days: float | None) -> timedelta:
    from supervisor.settings import get_settings
    from supervisor.users.service import default_ttl

    return timedelta(days=days) if days else default_ttl(kind, get_settings())


@app.command("create")
def create(
    name: str = typer.Argument(..., help="Username."),
    role: str = typer.Option(..., help=ROLE_HELP),
    password: bool = typer.Option(False, "--password", help="Ask for a password to sign in with."),
    token_name: str = typer.Option("cli", help="Name of the token printed."),
    ttl_days: float | None = typer.Option(
        None, min=0.001, help="Token lifetime; default VISTA_CLI_TOKEN_TTL_DAYS (device: …DEVICE…)."
    ),
) -> None:
    """Create a user and print an API token for it (shown once)."""
    from supervisor.models.users import ROLES
    from supervisor.users.service import create_token, create_user, name_taken

    if role not in ROLES:
        fail(f"--role must be one of {', '.join(ROLES)}, not {role!r}")
    if password and role == "device":
        fail("device accounts sign in with tokens only: drop --password")
    with _database() as session:
        if name_taken(session, name):
            fail(f"a user named {name!r} already exists")
    secret = _ask_password() if password else None  # hashed, before the transaction
    kind = "device" if role == "device" else "cli"
    with _database() as session:
        user = create_user(session, username=name, role=role, password_hash=secret)
        token = create_token(
            session, user=user, name=token_name, kind=kind, ttl=_ttl(kind, ttl_days)
        )
    typer.echo(token)


@app.command("list")
def list_users() -> None:
    """Every user: id, name, role, active, working tokens."""
    from sqlalchemy import func, select

    from supervisor.models import ApiToken, User
    from supervisor.models._types import utcnow

    with _database() as session:
        working = (
            select(ApiToken.user_id, func.count().label("tokens"))
            .where(ApiToken.revoked.is_(False), ApiToken.expires_at > utcnow())
            .group_by(ApiToken.user_id)
            .subquery()
        )
        rows = session.execute(
            select(User, func.coalesce(working.c.tokens, 0))
            .outerjoin(working, working.c.user_id == User.id)
            .order_by(User.id)
        ).all()
        typer.echo(f"{'id':>5}  {'user':<24} {'role':<10} {'active':<7} tokens")
        for user, tokens in rows:
            active = "yes" if user.active else "no"
            typer.echo(f"{user.id:>5}  {user.username:<24} {user.role:<10} {active:<7} {tokens}")


@app.command("token")
def token(
    name: str = typer.Argument(..., help="Username."),
    token_name: str = typer.Option("cli", help="What the token is for (a device's name)."),
    kind: str = typer.Option("cli", help="cli or device."),
    ttl_days: float | None = typer.Option(
        None, min=0.001, help="Lifetime; default VISTA_CLI_TOKEN_TTL_DAYS or …DEVICE…."
    ),
) -> None:
    """Issue another token for a user and print it (shown once)."""
    from supervisor.users.service import by_name, create_token

    if kind not in ("cli", "device"):
        fail(f"--kind must be cli or device, not {kind!r}")
    with _database() as session:
        user = by_name(session, name)
        issued = create_token(
            session, user=user, name=token_name, kind=kind, ttl=_ttl(kind, ttl_days)
        )
    typer.echo(issued)


@app.command("tokens")
def tokens(
    name: str | None = typer.Argument(None, help="Only this user's tokens."),
    all_: bool = typer.Option(False, "--all", help="Also revoked and expired tokens."),
) -> None:
    """Tokens (never the token itself): id, user, kind, name, expiry, state."""
    from supervisor.models._types import utcnow
    from supervisor.users.service import by_name, tokens_query, usernames

    with _database() as session:
        user_id = by_name(session, name).id if name else None
        rows = session.scalars(tokens_query(user_id=user_id, include_ended=all_)).all()
        names = usernames(session, {row.user_id for row in rows})
        now = utcnow()
        typer.echo(f"{'id':>5}  {'user':<20} {'kind':<8} {'name':<20} {'expires':<17} state")
        for row in rows:
            state = (
                "revoked"
                if row.revoked
                else "expired"
                if row.expires_at and row.expires_at <= now
                else "working"
            )
            expires = row.expires_at.strftime("%Y-%m-%d %H:%M") if row.expires_at else "never"
            typer.echo(
                f"{row.id:>5}  {names[row.user_id]:<20} {row.kind:<8} {row.name:<20} "
                f"{expires:<17} {state}"
            )


@app.command("revoke")
def revoke(
    token_id: int | None = typer.Option(None, "--token", help="One token, by id (see tokens)."),
    user: str | None = typer.Option(None, help="Every token of this user."),
    device: str | None = typer.Option(None, help="Every device token of this name."),
    reason: str = typer.Option("", help="Kept in the audit log."),
) -> None:
    """Revoke tokens: they stop working at the next request."""
    from supervisor.audit.service import COMMAND_LINE
    from supervisor.users.service import by_name, revoke

    if sum(x is not None for x in (token_id, user, device)) != 1:
        fail("give exactly one of --token, --user and --device")
    with _database(revokes=True) as session:
        if user is not None:
            where = {"user_id": by_name(session, user).id}
        elif device is not None:
            where = {"kind": "device", "name": device}
        else:
            where = {"token_id": token_id}
        ids = revoke(session, actor=COMMAND_LINE, reason=reason, **where)
    typer.echo(f"revoked {len(ids)} token(s){': ' + ', '.join(map(str, ids)) if ids else ''}")


def _change(name: str, **change: object) -> None:
    from supervisor.audit.service import COMMAND_LINE
    from supervisor.users.service import by_name, change_user

    with _database(revokes=True) as session:
        change_user(session, by_name(session, name), actor=COMMAND_LINE, **change)


@app.command("deactivate")
def deactivate(name: str = typer.Argument(..., help="Username.")) -> None:
    """Deactivate a user: they cannot sign in and their tokens stop working at once."""
    _change(name, active=False)
    typer.echo(f"{name} is deactivated; their tokens are revoked")


@app.command("reactivate")
def reactivate(name: str = typer.Argument(..., help="Username.")) -> None:
    """Let a deactivated user sign in again (issue them new tokens: the old stay revoked)."""
    _change(name, active=True)
    typer.echo(f"{name} is active again")


@app.command("set-password")
@app.command("password", hidden=True)  # its earlier name
def password(name: str = typer.Argument(..., help="Username.")) -> None:
    """Set a user's password (asked twice), e.g. for an admin made without one."""
    from supervisor.users.service import by_name

    with _database() as session:
        by_name(session, name)  # an unknown name fails before the password is asked
    _change(name, password_hash=_ask_password())
    typer.echo(f"{name}'s password is set")


@app.command("role")
def role(
    name: str = typer.Argument(..., help="Username."),
    to: str = typer.Argument(..., help=ROLE_HELP),
) -> None:
    """Change a user's role (the last active admin stays one)."""
    from supervisor.models.users import ROLES

    if to not in ROLES:
        fail(f"the role must be one of {', '.join(ROLES)}, not {to!r}")
    _change(name, role=to)
    typer.echo(f"{name} is now {to}")
