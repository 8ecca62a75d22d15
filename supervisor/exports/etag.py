"""The scene's version: it changes exactly when something the scene shows changes."""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from supervisor.models import Change

SCENE_FORMAT = 3
"""Bumped whenever the export itself changes, so caches do not serve the old layout."""


def scene_version(session: Session, *, inspection_id: int) -> int:
    """The last change-log position of anything the scene shows (jobs' progress is not)."""
    return (
        session.scalar(
            select(func.max(Change.seq)).where(
                Change.inspection_id == inspection_id, Change.entity != "job"
            )
        )
        or 0
    )


def scene_etag(
    session: Session, *, inspection_id: int, max_points: int, run_id: int | None = None
) -> str:
    """The version of the scene of run ``run_id`` (None: the inspection's, which shows its
    newest measured run)."""
    version = scene_version(session, inspection_id=inspection_id)
    shown = f"run{run_id}" if run_id is not None else "newest"
    return f'"scene-{SCENE_FORMAT}-{inspection_id}-{shown}-{version}-{max_points}"'
