"""job kinds named <service>.<verb>: stored jobs take the new names

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-26 19:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

RENAMED = {
    "calibrate": "stitching.calibrate",
    "stitch": "stitching.stitch",
    "measure": "defects.measure",
    "odometry": "odometry.run",
    "track": "tracking.track",
    "track.train": "tracking.train",
}
"""Old name → new (the kinds accept the old names as aliases for a release)."""


def _rename(pairs: dict[str, str]) -> None:
    jobs = sa.table("jobs", sa.column("kind", sa.String))
    for old, new in pairs.items():
        op.execute(jobs.update().where(jobs.c.kind == old).values(kind=new))


def upgrade() -> None:
    _rename(RENAMED)


def downgrade() -> None:
    _rename({new: old for old, new in RENAMED.items()})
