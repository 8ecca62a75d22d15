"""One grammar for every command: `vista <service> <verb>`, a job kind `service.verb` and
its command the same words, each parameter written once (a command's options for a job's
parameters are the kind's Params fields: same names, defaults and ranges), and the older
spellings hidden aliases."""

from __future__ import annotations

from pathlib import Path

import pytest
import typer
from annotated_types import Ge, Le
from pydantic import BaseModel, Field

from contract.cli import params_options
from supervisor.cli import app
from supervisor.engine.registry import all_kinds, load_kinds

EXECUTION_OPTIONS = {"threads"}
"""Options a command may have beside its job's parameters and its files (any option typed
as a path): how many threads it runs on. Anything that changes a result is a Params field,
so a job can set it too."""


# Typer vendors its own Click: its commands and parameters are told apart by what they
# have (a group its ``commands``, an option its ``param_type_name``), not by class.


def root():
    return typer.main.get_command(app)


def service_kinds() -> list:
    """The services' job kinds (a test's own kinds, registered beside them, have no command)."""
    load_kinds()
    return [k for k in all_kinds() if k.handler.startswith("services.")]


def command_of(group, kind_name: str):
    service, verb = kind_name.split(".", 1)
    own = group.commands.get(service)
    return own.commands.get(verb) if hasattr(own, "commands") else None


def _bounds(info) -> tuple[float | None, float | None]:
    low = next((m.ge for m in info.metadata if isinstance(m, Ge)), None)
    high = next((m.le for m in info.metadata if isinstance(m, Le)), None)
    return low, high


def disagreements(command, model: type[BaseModel]) -> list[str]:
    """Where ``command``'s options and ``model``'s fields part: a field without its option
    (unless the command fixes it), another default or range, an option that is neither a
    field nor about files and execution."""
    fixed = getattr(command.callback, "fixed_params", frozenset())
    options = {p.name: p for p in command.params if p.param_type_name == "option"}
    found = []
    for name, info in model.model_fields.items():
        if name in fixed:
            continue
        option = options.get(name)
        if option is None:
            found.append(f"--{name.replace('_', '-')}: no option for the parameter")
            continue
        default = None if info.is_required() else info.default
        if option.default != default and not (option.required and info.is_required()):
            found.append(f"--{name}: default {option.default!r}, the parameter's {default!r}")
        low, high = _bounds(info)
        shown = (option.min, option.max)
        if (low, high) != (None, None) and shown != (low, high):
            found.append(f"--{name}: range {shown}, the parameter's {(low, high)}")
    for name in sorted(set(options) - set(model.model_fields) - EXECUTION_OPTIONS - {"help"}):
        if "Path" not in str(options[name].type_descriptor.annotation):
            found.append(f"--{name}: not a parameter of the job, nor a file")
    return found


def test_every_job_kind_has_its_command_with_its_parameters():
    group = root()
    kinds = service_kinds()
    assert len(kinds) >= 11
    missing = [k.name for k in kinds if command_of(group, k.name) is None]
    assert missing == []
    parted = {k.name: disagreements(command_of(group, k.name), k.params) for k in kinds}
    assert {k: v for k, v in parted.items() if v} == {}


class _Planted(BaseModel):
    passes: int = Field(3, ge=1, le=10, description="How many passes.")
    method: str = Field("fast", description="Which method.")


def test_a_command_restating_a_parameter_is_found():
    planted = typer.Typer()

    @planted.command("good")
    @params_options(_Planted)
    def good(out: Path = typer.Option(None), *, params: _Planted) -> None: ...

    @planted.command("drifted")
    def drifted(
        passes: int = typer.Option(4, min=1, max=10),
        strength: float = typer.Option(0.5),
    ) -> None: ...

    group = typer.main.get_command(planted)
    assert disagreements(group.commands["good"], _Planted) == []
    assert disagreements(group.commands["drifted"], _Planted) == [
        "--passes: default 4, the parameter's 3",
        "--method: no option for the parameter",
        "--strength: not a parameter of the job, nor a file",
    ]


def test_every_command_is_service_then_verb():
    """The top level holds the services (and the supervisor's own verbs); what is hidden
    there is an older spelling, still working and marked deprecated."""
    group = root()
    services = {k.name.split(".")[0] for k in service_kinds()}
    supervisor_verbs = {"migrate", "serve", "worker", "demo", "precompile", "user"}
    benched = {"api", "clients"}
    shown = {n for n, c in group.commands.items() if not c.hidden}
    assert shown == services | supervisor_verbs | benched
    hidden = {n: c for n, c in group.commands.items() if c.hidden}
    assert {"simulate", "bench", "measure", "stitch", "calibrate"} <= set(hidden)
    assert all(c.deprecated for c in hidden.values())
    for name in services - {"scan"}:
        verbs = group.commands[name].commands
        assert {"simulate", "bench"} <= set(verbs), name
    for name in ("api", "clients"):
        assert set(group.commands[name].commands) == {"bench"}


@pytest.mark.parametrize(
    ("old", "new"),
    [
        (["simulate", "defects"], ["defects", "simulate"]),
        (["bench", "stitching"], ["stitching", "bench"]),
        (["bench", "api"], ["api", "bench"]),
        (["measure"], ["defects", "measure"]),
    ],
)
def test_an_older_spelling_runs_the_same_command(old, new):
    group = root()

    def resolve(words: list[str]):
        command = group
        for word in words:
            command = command.commands[word]
        return command

    assert resolve(old).callback is resolve(new).callback or (
        resolve(old).callback.__wrapped__ is resolve(new).callback.__wrapped__
    )
    assert resolve(old).hidden or resolve(old[:1]).hidden
