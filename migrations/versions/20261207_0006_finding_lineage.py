"""findings' lineage across measurements: which finding a later run's continues, why one
is no longer current, and the run a carried judgment was made on

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-07 12:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

KEEP_IDS = {"sqlite_autoincrement": True}
"""A table SQLite rebuilds keeps AUTOINCREMENT: a deleted row's id is never handed out again."""


def upgrade() -> None:
    with op.batch_alter_table("defects", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.add_column(sa.Column("lineage_id", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("supersedes_id", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("superseded_by_id", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("ended", sa.String(length=16), nullable=True))
        batch_op.add_column(sa.Column("ended_run_id", sa.Integer(), nullable=True))
        for column, table in (
            ("supersedes_id", "defects"),
            ("superseded_by_id", "defects"),
            ("ended_run_id", "runs"),
        ):
            batch_op.create_foreign_key(
                batch_op.f(f"fk_defects_{column}_{table}"),
                table,
                [column],
                ["id"],
                ondelete="SET NULL",
            )
        batch_op.create_check_constraint(
            batch_op.f("ck_defects_ended"), "ended IN ('superseded', 'not found again')"
        )
        batch_op.create_index(batch_op.f("ix_defects_lineage_id"), ["lineage_id"])
        batch_op.create_index(batch_op.f("ix_defects_ended"), ["ended"])
    op.execute("UPDATE defects SET lineage_id = id")
    for table in ("judgments", "judgment_revisions"):
        with op.batch_alter_table(table, table_kwargs=KEEP_IDS) as batch_op:
            batch_op.add_column(sa.Column("judged_on_run_id", sa.Integer(), nullable=True))


def downgrade() -> None:
    for table in ("judgments", "judgment_revisions"):
        with op.batch_alter_table(table, table_kwargs=KEEP_IDS) as batch_op:
            batch_op.drop_column("judged_on_run_id")
    with op.batch_alter_table("defects", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.drop_index(batch_op.f("ix_defects_ended"))
        batch_op.drop_index(batch_op.f("ix_defects_lineage_id"))
        batch_op.drop_constraint(batch_op.f("ck_defects_ended"), type_="check")
        for column, table in (
            ("ended_run_id", "runs"),
            ("superseded_by_id", "defects"),
            ("supersedes_id", "defects"),
        ):
            batch_op.drop_constraint(batch_op.f(f"fk_defects_{column}_{table}"), type_="foreignkey")
        for column in ("ended_run_id", "ended", "superseded_by_id", "supersedes_id", "lineage_id"):
            batch_op.drop_column(column)
