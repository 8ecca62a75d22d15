"""Job kinds: what each one is called, which queue runs it, its parameters and handler.

Handlers are named by import path and imported only inside a worker, so the API process
never loads a service's heavy libraries.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

BUILTIN_KIND_MODULES = ("services.scan.kinds", "services.stitching.kinds", "services.defects.kinds")


ANY_KIND = "*"


@dataclass(frozen=True)
class Inputs:
    """How many artifacts of these kinds one step of a job kind reads."""

    kinds: tuple[str, ...]
    what: str
    """What they are, for people: "the stitched point cloud"."""
    min: int = 1
    max: int | None = 1
    """``None``: no upper limit."""

    def accepts(self, kind: str) -> bool:
        return ANY_KIND in self.kinds or kind in self.kinds


@dataclass(frozen=True)
class Output:
    """An artifact a job kind writes; ``per_input`` ones are written once per input."""

    kind: str
    name: str
    per_input: bool = False


@dataclass(frozen=True)
class JobKind:
    name: str
    queue: str
    handler: str
    """``module:function`` taking a ``JobContext`` and returning a JSON-able dict."""
    params: type[BaseModel]
    description: str
    inputs: tuple[Inputs, ...] = ()
    """What the handler reads: checked when a run is created."""
    outputs: tuple[Output, ...] = ()
    """What it writes: a later step's inputs are checked against them."""

    @property
    def input_kinds(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(k for spec in self.inputs for k in spec.kinds))

    def load_handler(self) -> Callable[[Any], dict]:
        module_name, _, function = self.handler.partition(":")
        return getattr(importlib.import_module(module_name), function)


_KINDS: dict[str, JobKind] = {}
_loaded_modules: set[str] = set()


def register(kind: JobKind) -> JobKind:
    existing = _KINDS.get(kind.name)
    if existing is not None and existing != kind:
        raise ValueError(f"job kind {kind.name!r} is registered twice")
    _KINDS[kind.name] = kind
    return kind


def load_kinds(extra_modules: list[str] | tuple[str, ...] = ()) -> dict[str, JobKind]:
    """Import the modules that register job kinds (built-in ones plus ``extra_modules``)."""
    for module in (*BUILTIN_KIND_MODULES, *extra_modules):
        if module not in _loaded_modules:
            importlib.import_module(module)
            _loaded_modules.add(module)
    return dict(_KINDS)


def get_kind(name: str) -> JobKind | None:
    return _KINDS.get(name)


def all_kinds() -> list[JobKind]:
    return list(_KINDS.values())


def queues() -> list[str]:
    return sorted({kind.queue for kind in _KINDS.values()})
