"""Whether a run's step gets what its job kind reads: checked when the run is created,
so a run that cannot work is refused at once instead of failing when its job runs."""

from __future__ import annotations

from contract.kinds import Inputs, JobKind
from supervisor.problems import Problem


def check_step_inputs(
    where: str,
    kind: JobKind,
    *,
    given: dict[int, str],
    upstream: dict[str, JobKind],
    producers: list[JobKind],
    params: dict | None = None,
) -> None:
    """``given``: the step's own input artifacts (id → artifact kind); ``upstream``: its
    ``after`` steps' kinds by step name, whose outputs it also reads; ``producers``: every job
    kind, to say which step could make a missing input; ``params``: the step's, for inputs
    needed or read only with some of them. Raises a 422 naming the problem."""
    params = params or {}
    for artifact_id, artifact_kind in given.items():
        if not any(spec.accepts(artifact_kind) for spec in kind.inputs):
            raise Problem(
                422,
                f"{where}.inputs: artifact {artifact_id} is a '{artifact_kind}', which "
                f"{kind.name} does not read; it reads {_reads(kind)}.",
            )
    for spec in kind.inputs:
        own = [i for i, k in given.items() if spec.accepts(k)]
        made = [(s, o) for s, up in upstream.items() for o in up.outputs if spec.accepts(o.kind)]
        at_least = len(own) + len(made)
        at_most = None if any(o.per_input for _, o in made) else at_least
        if at_least < spec.min:
            raise Problem(422, f"{where}: {_missing(kind, spec, at_least, producers)}")
        if spec.needed_when and at_least == 0:
            name, values = spec.needed_when
            if params.get(name) in values:
                missing = _missing(kind, spec, 0, producers, count="one")
                needed = f"with {name} {params[name]}, {missing}"
                raise Problem(422, f"{where}: {needed}")
        if spec.only_when and at_least > 0:
            name, values = spec.only_when
            if params.get(name) not in values:
                raise Problem(
                    422,
                    f"{where}: with {name} {params.get(name)}, {kind.name} reads no "
                    f"{_kinds(spec)} ({spec.what}): leave it out, or set {name} to "
                    f"{' or '.join(values)}.",
                )
        if spec.max is not None and at_most is not None and at_most > spec.max:
            sources = [f"artifact {i}" for i in own] + [f"{o.name} of step {s!r}" for s, o in made]
            raise Problem(
                422,
                f"{where}: {kind.name} reads {_count(spec)} {_kinds(spec)} ({spec.what}); "
                f"it would get {at_most}: {', '.join(sources)}.",
            )


def _kinds(spec: Inputs) -> str:
    return " or ".join(f"'{k}'" for k in spec.kinds)


def _count(spec: Inputs) -> str:
    if spec.max is None:
        return f"at least {spec.min}"
    return f"exactly {spec.min}" if spec.min == spec.max else f"{spec.min} to {spec.max}"


def _reads(kind: JobKind) -> str:
    if not kind.inputs:
        return "no artifacts"
    return "; ".join(f"{_count(s)} {_kinds(s)} ({s.what})" for s in kind.inputs)


def _missing(
    kind: JobKind, spec: Inputs, got: int, producers: list[JobKind], count: str | None = None
) -> str:
    makers = (
        list(spec.made_by)
        if spec.made_by is not None
        else sorted(
            p.name
            for p in producers
            if p.name != kind.name and any(spec.accepts(o.kind) for o in p.outputs)
        )
    )
    hint = f"upload it as kind {_kinds(spec)} and list its id in inputs"
    if makers:
        hint += " or list a step of kind " + " or ".join(f"'{m}'" for m in makers) + " in after"
    return (
        f"{kind.name} needs {count or _count(spec)} {_kinds(spec)} artifact ({spec.what}) and "
        f"gets {got or 'none'}: {hint}."
    )
