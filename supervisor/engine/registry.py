"""The job kinds and artifact kinds this installation knows: collected from the services.

Each module named here (and each in ``VISTA_EXTRA_JOB_KINDS``) declares, as data, its job
kinds in a ``KINDS`` tuple of ``contract.kinds.JobKind`` and the kinds of file only it knows
in an ``ARTIFACT_KINDS`` tuple of ``contract.artifacts.ArtifactKind`` (either may be absent,
not both), and may name (``module:function``) its commands' ``register(app, simulate_app,
bench_app)`` in ``CLI``, the writer of the demo's simulated data in ``DEMO_EXAMPLE`` and
what compiles its numba kernels into their cache (`vista precompile`) in ``PRECOMPILE``;
importing it has no other effect. This is the supervisor's one way to a service: everything
else it learns through the hooks these declarations name.
"""

from __future__ import annotations

import importlib

from contract.artifacts import ArtifactKind
from contract.kinds import JobKind, load_hook

SERVICE_KIND_MODULES = (
    "services.lib.artifact_kinds",
    "services.scan.kinds",
    "services.stitching.kinds",
    "services.defects.kinds",
    "services.odometry.kinds",
    "services.depth.kinds",
    "services.tracking.kinds",
)

_KINDS: dict[str, JobKind] = {}
_ARTIFACT_KINDS: dict[str, ArtifactKind] = {}
_ALIASES: dict[str, str] = {}


def load_kinds(extra_modules: list[str] | tuple[str, ...] = ()) -> dict[str, JobKind]:
    """The job kinds of the services and of ``extra_modules``, by name (their artifact kinds
    are kept for ``artifact_kinds``); a name declared twice with different contents is an
    error."""
    for module in (*SERVICE_KIND_MODULES, *extra_modules):
        loaded = importlib.import_module(module)
        declared = getattr(loaded, "KINDS", None)
        files = getattr(loaded, "ARTIFACT_KINDS", None)
        if declared is None and files is None:
            raise ValueError(
                f"{module} declares neither KINDS (a tuple of contract.kinds.JobKind) nor "
                "ARTIFACT_KINDS (a tuple of contract.artifacts.ArtifactKind)"
            )
        _add(_KINDS, declared or (), "job kind")
        _add(_ARTIFACT_KINDS, files or (), "artifact kind")
        for kind in declared or ():
            for alias in kind.aliases:
                if alias in _KINDS or _ALIASES.get(alias, kind.name) != kind.name:
                    raise ValueError(f"job kind alias {alias!r} names another kind too")
                _ALIASES[alias] = kind.name
    return dict(_KINDS)


def _add(known: dict, declared: tuple, what: str) -> None:
    for kind in declared:
        existing = known.get(kind.name)
        if existing is not None and existing != kind:
            raise ValueError(f"{what} {kind.name!r} is declared twice")
        known[kind.name] = kind


def get_kind(name: str) -> JobKind | None:
    """The kind called ``name`` or, for an older name, the kind it now names."""
    return _KINDS.get(_ALIASES.get(name, name))


def all_kinds() -> list[JobKind]:
    return list(_KINDS.values())


def artifact_kinds() -> dict[str, ArtifactKind]:
    """Every artifact kind by name (the services' own; ``load_kinds`` adds extras')."""
    if not _ARTIFACT_KINDS:
        load_kinds()
    return dict(_ARTIFACT_KINDS)


def declared_hooks(name: str) -> list:
    """The functions the service modules name in their ``name`` attribute (``CLI``,
    ``DEMO_EXAMPLE``, ``PRECOMPILE``), in the modules' order, imported now."""
    found = (getattr(importlib.import_module(m), name, None) for m in SERVICE_KIND_MODULES)
    return [load_hook(path) for path in found if path is not None]


def queues() -> list[str]:
    return sorted({kind.queue for kind in _KINDS.values()})
