"""named tolerance sets reusable across inspections, and the set an inspection applied

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-07 13:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JSON = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")
KEEP_IDS = {"sqlite_autoincrement": True}
"""A table SQLite rebuilds keeps AUTOINCREMENT: a deleted row's id is never handed out again."""


def upgrade() -> None:
    op.create_table(
        "tolerance_sets",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=100), nullable=False),
        sa.Column("description", sa.String(length=2000), nullable=False),
        sa.Column("tolerances", JSON, nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("created_by", sa.Integer(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["created_by"],
            ["users.id"],
            name=op.f("fk_tolerance_sets_created_by_users"),
            ondelete="SET NULL",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_tolerance_sets")),
        sa.UniqueConstraint("name", name=op.f("uq_tolerance_sets_name")),
        sqlite_autoincrement=True,
    )
    with op.batch_alter_table("inspections", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.add_column(sa.Column("tolerance_set", JSON, nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("inspections", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.drop_column("tolerance_set")
    op.drop_table("tolerance_sets")
