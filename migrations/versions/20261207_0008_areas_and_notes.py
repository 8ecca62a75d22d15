"""an inspection's area in the user's words (not only cabin, cargo, component), and the
notes people add to a finding

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-07 14:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0008"
down_revision: str | None = "0007"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JSON = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")
KEEP_IDS = {"sqlite_autoincrement": True}
"""A table SQLite rebuilds keeps AUTOINCREMENT: a deleted row's id is never handed out again."""


def upgrade() -> None:
    with op.batch_alter_table("inspections", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.drop_constraint(batch_op.f("ck_inspections_area"), type_="check")
        batch_op.alter_column(
            "area", existing_type=sa.String(length=16), type_=sa.String(length=64)
        )
    with op.batch_alter_table("defects", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.add_column(sa.Column("notes", JSON, nullable=False, server_default="[]"))


def downgrade() -> None:
    with op.batch_alter_table("defects", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.drop_column("notes")
    op.execute(
        "UPDATE inspections SET area = 'component' "
        "WHERE area NOT IN ('cargo', 'cabin', 'component')"
    )
    with op.batch_alter_table("inspections", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.alter_column(
            "area", existing_type=sa.String(length=64), type_=sa.String(length=16)
        )
        batch_op.create_check_constraint(
            batch_op.f("ck_inspections_area"), "area IN ('cargo', 'cabin', 'component')"
        )
