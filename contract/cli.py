"""How every `vista` command refuses (a red sentence on stderr and exit status 2), reports a
long task's progress, and takes a job's parameters: the options of a command that does what
a job kind does are made from the kind's ``Params`` model (``params_options``), so a
parameter is declared once — type, default, range and help alike."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, NoReturn

import typer
from annotated_types import Ge, Le
from pydantic import BaseModel, ValidationError


def fail(message: str) -> NoReturn:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def unwrap_help(app: typer.Typer) -> None:
    """Every command's help as paragraphs of joined lines: a docstring's line breaks are the
    source's, and Typer's rich help keeps them, which breaks sentences in the middle of a
    terminal line."""
    for command in app.registered_commands:
        text = command.help or inspect.getdoc(command.callback) or ""
        paragraphs = text.split("\n\n")
        command.help = "\n\n".join(
            " ".join(line.strip() for line in p.splitlines()) for p in paragraphs
        )
    for group in app.registered_groups:
        unwrap_help(group.typer_instance)


PROGRESS_STEPS = 1000


@contextmanager
def progress_bar(label: str) -> Iterator[Callable[..., None]]:
    """A bar drawn from its first step on, so an error found before the work starts is the
    only line printed. Each call gives the fraction done and, optionally, what is being
    done (the bar's label)."""
    bar = None
    shown = 0

    def step(fraction: float, message: str | None = None) -> None:
        nonlocal bar, shown
        if bar is None:
            bar = typer.progressbar(length=PROGRESS_STEPS, label=label)
            bar.__enter__()
        if message:
            bar.label = message[:60]
        reached = int(min(max(fraction, 0.0), 1.0) * PROGRESS_STEPS)
        if reached > shown:
            bar.update(reached - shown)
            shown = reached

    try:
        yield step
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)


def echo_progress(fraction: float, message: str) -> None:
    """A training's or a batch's progress line: ``[ 42.0 %] message``."""
    typer.echo(f"[{fraction * 100:5.1f} %] {message}")


def alias(app: typer.Typer, old: str, command: Callable[..., None], new: str) -> None:
    """``vista <old>`` kept for a release as a hidden alias of ``vista <new>``: it works,
    says it is deprecated when run, and is not listed in ``--help`` (the README lists the
    old spellings)."""
    app.command(
        old,
        hidden=True,
        deprecated=True,
        help=f"Alias of `vista {new}` (kept for this release).",
    )(command)


def params_options(
    model: type[BaseModel],
    *,
    fixed: dict[str, Any] | None = None,
    text: dict[str, tuple[str, Callable[[str], Any]]] | None = None,
) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Decorate a command taking ``params: model``: its options become one per field of
    ``model`` (``--field-name``, the field's type, default, range and description), checked
    by the model (a refusal names the option) and handed over as one ``params``. ``fixed``:
    fields the command sets itself (``network="teacher"``); ``text``: fields typed on the
    command line as one string, with the option's help and the parser to the field's value
    (``--init-box "h w l x y z ry"``)."""
    text, fixed = text or {}, fixed or {}

    def decorate(command: Callable[..., None]) -> Callable[..., None]:
        signature = inspect.signature(command)
        own = [p for p in signature.parameters.values() if p.name != "params"]
        fields = {n: f for n, f in model.model_fields.items() if n not in fixed}
        made = [_option(name, info, text.get(name)) for name, info in fields.items()]

        @functools.wraps(command)
        def run(**given: Any) -> None:
            values = {name: given.pop(name) for name in fields} | fixed
            try:
                for name, (_, parse) in text.items():
                    if values.get(name) is not None:
                        values[name] = parse(values[name])
                params = model.model_validate({k: v for k, v in values.items() if v is not None})
            except ValidationError as exc:
                fail(_in_option_words(exc))
            except ValueError as exc:
                fail(str(exc))
            return command(params=params, **given)

        run.__signature__ = signature.replace(parameters=[*own, *made])
        run.fixed_params = frozenset(fixed)  # read by the grammar's test
        return run

    return decorate


def _option(name: str, info: Any, text: tuple[str, Callable[[str], Any]] | None) -> Any:
    optional = not info.is_required() and info.default is None
    if text is not None:
        annotation, help_text = (str | None), text[0]
    else:
        annotation, help_text = info.annotation, info.description
    bounds = {}  # shown in --help and checked by typer; gt/lt are the model's to check
    for item in info.metadata:
        if isinstance(item, Ge):
            bounds["min"] = item.ge
        elif isinstance(item, Le):
            bounds["max"] = item.le
    default = ... if info.is_required() else info.default
    return inspect.Parameter(
        name,
        inspect.Parameter.KEYWORD_ONLY,
        annotation=annotation,
        default=typer.Option(default, help=help_text, show_default=not optional, **bounds),
    )


def _in_option_words(error: ValidationError) -> str:
    """A model's first refusal as the option's: "--pitch-mm: Input should be ≥ 0.2"."""
    first = error.errors()[0]
    message = first["msg"].removeprefix("Value error, ")
    field = next((str(p) for p in first["loc"] if isinstance(p, str)), None)
    return f"--{field.replace('_', '-')}: {message}" if field else message
