"""ids never reused (SQLite AUTOINCREMENT), inspections' trash, who set a defect's status
and why, revocation times, the audit log

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-26 14:40:00
"""

from collections.abc import Sequence
from datetime import UTC, datetime, timedelta

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JSON = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")
# Every table with a single integer key. On SQLite each is rebuilt (rows kept, ids kept)
# with AUTOINCREMENT, so a deleted row's id is never handed out again; env.py turns the
# foreign keys off while a table is rebuilt so dropping the old copy cascades nothing.
ID_TABLES = (
    "users",
    "api_tokens",
    "inspections",
    "artifacts",
    "runs",
    "jobs",
    "defects",
    "judgments",
    "judgment_revisions",
    "sync_receipts",
    "changes",
    "idempotency_records",
)


def _autoincrement(enabled: bool) -> None:
    if op.get_bind().dialect.name != "sqlite":
        return  # PostgreSQL: serial columns already never reuse an id
    for table in ID_TABLES:
        with op.batch_alter_table(
            table, recreate="always", table_kwargs={"sqlite_autoincrement": enabled}
        ):
            pass


def upgrade() -> None:
    with op.batch_alter_table("inspections", schema=None) as batch_op:
        batch_op.add_column(sa.Column("deleted_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.add_column(sa.Column("deleted_by", sa.Integer(), nullable=True))
        batch_op.create_foreign_key(
            batch_op.f("fk_inspections_deleted_by_users"),
            "users",
            ["deleted_by"],
            ["id"],
            ondelete="SET NULL",
        )
        batch_op.create_index(batch_op.f("ix_inspections_deleted_at"), ["deleted_at"])
    with op.batch_alter_table("defects", schema=None) as batch_op:
        batch_op.add_column(sa.Column("status_by", sa.Integer(), nullable=True))
        batch_op.add_column(
            sa.Column("status_reason", sa.Text(), nullable=False, server_default="")
        )
        batch_op.create_foreign_key(
            batch_op.f("fk_defects_status_by_users"),
            "users",
            ["status_by"],
            ["id"],
            ondelete="SET NULL",
        )
    with op.batch_alter_table("api_tokens", schema=None) as batch_op:
        batch_op.add_column(sa.Column("revoked_at", sa.DateTime(timezone=True), nullable=True))
    # Every token expires now: those made without a lifetime get the CLI tokens' default.
    tokens = sa.table("api_tokens", sa.column("expires_at", sa.DateTime(timezone=True)))
    op.execute(
        tokens.update()
        .where(tokens.c.expires_at.is_(None))
        .values(expires_at=datetime.now(UTC) + timedelta(days=90))
    )
    op.create_table(
        "audit_events",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("user_id", sa.Integer(), nullable=True),
        sa.Column("username", sa.String(length=64), nullable=False),
        sa.Column("action", sa.String(length=32), nullable=False),
        sa.Column("entity", sa.String(length=32), nullable=False),
        sa.Column("entity_id", sa.Integer(), nullable=False),
        sa.Column("inspection_id", sa.Integer(), nullable=True),
        sa.Column("before", JSON, nullable=True),
        sa.Column("after", JSON, nullable=True),
        sa.Column("reason", sa.Text(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_audit_events")),
        sqlite_autoincrement=True,
    )
    with op.batch_alter_table("audit_events", schema=None) as batch_op:
        batch_op.create_index("ix_audit_events_entity_entity_id", ["entity", "entity_id"])
        batch_op.create_index(batch_op.f("ix_audit_events_user_id"), ["user_id"])
        batch_op.create_index(batch_op.f("ix_audit_events_inspection_id"), ["inspection_id"])
    _autoincrement(True)  # last: a later batch rebuild would drop AUTOINCREMENT again


def downgrade() -> None:
    op.drop_table("audit_events")
    with op.batch_alter_table("api_tokens", schema=None) as batch_op:
        batch_op.drop_column("revoked_at")
    with op.batch_alter_table("defects", schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f("fk_defects_status_by_users"), type_="foreignkey")
        batch_op.drop_column("status_reason")
        batch_op.drop_column("status_by")
    with op.batch_alter_table("inspections", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_inspections_deleted_at"))
        batch_op.drop_constraint(batch_op.f("fk_inspections_deleted_by_users"), type_="foreignkey")
        batch_op.drop_column("deleted_by")
        batch_op.drop_column("deleted_at")
    _autoincrement(False)
