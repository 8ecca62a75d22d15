"""Checking an uploaded file before it is kept: its content must be what its kind needs,
whatever media type was declared. The check is the kind's own ``inspect`` hook, declared by
the service that knows the kind (``contract.artifacts``)."""

from __future__ import annotations

from pathlib import Path

from contract.artifacts import ArtifactRefused
from supervisor.engine.registry import artifact_kinds
from supervisor.problems import Problem


def validate_upload(path: Path, *, media_type: str, name: str, kind: str) -> tuple[str, dict]:
    """The media type to keep and the metadata learned from the file; raises a 422 Problem
    (413 for its size alone) naming what is wrong if the content is not what ``kind``
    needs."""
    inspect = artifact_kinds()[kind].load_inspect()
    if inspect is None:
        return media_type, {}
    try:
        found = inspect(path, media_type)
    except ArtifactRefused as exc:
        status = 413 if exc.too_large else 422
        raise Problem(status, f"{name} (kind={kind}) {exc.reason}.") from exc
    return found.media_type, found.meta
