"""findings of type deviation: a surface off its nominal (CAD) beyond its profile band

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-07 18:00:00
"""

from collections.abc import Sequence

from alembic import op

revision: str = "0009"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

KEEP_IDS = {"sqlite_autoincrement": True}
"""A table SQLite rebuilds keeps AUTOINCREMENT: a deleted row's id is never handed out again."""
BEFORE = ("gap", "step", "parallelism", "mismatch", "scratch", "dent", "bump", "color")
AFTER = (*BEFORE, "deviation")


def _types(types: tuple[str, ...]) -> None:
    with op.batch_alter_table("defects", table_kwargs=KEEP_IDS) as batch_op:
        batch_op.drop_constraint(batch_op.f("ck_defects_type"), type_="check")
        batch_op.create_check_constraint(batch_op.f("ck_defects_type"), f"type IN {types}")


def upgrade() -> None:
    _types(AFTER)


def downgrade() -> None:
    op.execute("DELETE FROM defects WHERE type = 'deviation'")
    _types(BEFORE)
