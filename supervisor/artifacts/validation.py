"""Checking an uploaded file before it is kept: its content must be what its kind needs,
whatever media type was declared. The check is the kind's own ``inspect`` hook, declared by
the service that knows the kind (``contract.artifacts``)."""

from __future__ import annotations

import inspect as introspect
from pathlib import Path

from contract.artifacts import ArtifactRefused, Inspected
from services.lib.pointcloud.reader import ReadersBusy
from supervisor.engine.registry import artifact_kinds
from supervisor.problems import Problem


def validate_upload(
    path: Path, *, media_type: str, name: str, kind: str, units: str | None = None
) -> Inspected:
    """The media type to keep, the metadata learned from the file and the file written in
    its place, if any; raises a 422 Problem (413 for its size alone) naming what is wrong
    if the content is not what ``kind`` needs, or ``units`` are given for a kind of file
    that has none; a 429 with Retry-After when the host's cloud readers are all busy."""
    inspect = artifact_kinds()[kind].load_inspect()
    takes_units = inspect is not None and "units" in introspect.signature(inspect).parameters
    if units is not None and not takes_units:
        raise Problem(
            422, f"units apply to point clouds and nominals, not to a file of kind {kind}."
        )
    if inspect is None:
        return Inspected(media_type)
    try:
        return inspect(path, media_type, units=units) if takes_units else inspect(path, media_type)
    except ArtifactRefused as exc:
        status = 413 if exc.too_large else 422
        raise Problem(status, f"{name} (kind={kind}) {exc.reason}.") from exc
    except ReadersBusy as exc:
        retry = {"Retry-After": str(exc.retry_after_s)}
        raise Problem(429, f"{name} (kind={kind}) was not read: {exc}.", headers=retry) from exc
