"""How every `vista` command refuses (a red sentence on stderr and exit status 2) and
reports a long task's progress."""

from __future__ import annotations

from collections.abc import Callable
from typing import NoReturn

import typer


def fail(message: str) -> NoReturn:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def echo_progress(fraction: float, message: str) -> None:
    """A training's or a batch's progress line: ``[ 42.0 %] message``."""
    typer.echo(f"[{fraction * 100:5.1f} %] {message}")


def alias(app: typer.Typer, old: str, command: Callable[..., None], new: str) -> None:
    """``vista <old>`` kept for a release as an alias of ``vista <new>``: listed as
    deprecated in ``--help`` and in the README."""
    app.command(old, deprecated=True, help=f"Alias of `vista {new}` (kept for this release).")(
        command
    )
