"""The scene's version: it changes exactly when the scene's geometry changes — a cloud or
a result file (artifacts), a finding's marker made (a measurement, one added by hand), the
inspection made or its image markers moved. Judgments, statuses, comments, severities
travel in the sync's defect data, not in the scene, so a judgment costs a headset a sync
page, not a scene download."""

from __future__ import annotations

from sqlalchemy import and_, func, or_, select
from sqlalchemy.orm import Session

from supervisor.models import Change

SCENE_FORMAT = 4
"""Bumped whenever the export itself changes, so caches do not serve the old layout."""


GEOMETRY = or_(
    Change.entity == "artifact",
    and_(Change.entity == "defect", Change.op == "create"),
    and_(Change.entity == "inspection", Change.op.in_(("create", "geometry"))),
)
"""The change-log rows that change what a scene draws."""


def scene_version(session: Session, *, inspection_id: int) -> int:
    """The last change-log position of the scene's geometry (see the module docstring)."""
    return (
        session.scalar(
            select(func.max(Change.seq)).where(Change.inspection_id == inspection_id, GEOMETRY)
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
