"""The job kinds this installation runs: collected from the services' ``KINDS`` lists.

Each module named here (and each in ``VISTA_EXTRA_JOB_KINDS``) declares its kinds as data in
a ``KINDS`` tuple of ``contract.kinds.JobKind``; importing it has no other effect.
"""

from __future__ import annotations

import importlib

from contract.kinds import JobKind

SERVICE_KIND_MODULES = (
    "services.scan.kinds",
    "services.stitching.kinds",
    "services.defects.kinds",
    "services.odometry.kinds",
    "services.depth.kinds",
    "services.tracking.kinds",
)

_KINDS: dict[str, JobKind] = {}


def load_kinds(extra_modules: list[str] | tuple[str, ...] = ()) -> dict[str, JobKind]:
    """The kinds of the services and of ``extra_modules``, by name (also kept for
    ``get_kind``); a name declared twice with different contents is an error."""
    for module in (*SERVICE_KIND_MODULES, *extra_modules):
        declared = getattr(importlib.import_module(module), "KINDS", None)
        if declared is None:
            raise ValueError(f"{module} declares no KINDS (a tuple of contract.kinds.JobKind)")
        for kind in declared:
            existing = _KINDS.get(kind.name)
            if existing is not None and existing != kind:
                raise ValueError(f"job kind {kind.name!r} is declared twice")
            _KINDS[kind.name] = kind
    return dict(_KINDS)


def get_kind(name: str) -> JobKind | None:
    return _KINDS.get(name)


def all_kinds() -> list[JobKind]:
    return list(_KINDS.values())


def queues() -> list[str]:
    return sorted({kind.queue for kind in _KINDS.values()})
