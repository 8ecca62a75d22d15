"""headset sync (client times, receipts), inspection markers, change log by inspection

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-21 10:12:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JSON = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")


def upgrade() -> None:
    with op.batch_alter_table("judgments", schema=None) as batch_op:
        batch_op.add_column(sa.Column("client_time", sa.DateTime(timezone=True), nullable=True))
    with op.batch_alter_table("judgment_revisions", schema=None) as batch_op:
        batch_op.add_column(sa.Column("client_time", sa.DateTime(timezone=True), nullable=True))
    with op.batch_alter_table("inspections", schema=None) as batch_op:
        batch_op.add_column(sa.Column("markers", JSON, nullable=False, server_default="[]"))
    # The sync reads one inspection's changes after a cursor: one index does both.
    with op.batch_alter_table("changes", schema=None) as batch_op:
        batch_op.drop_index("ix_changes_inspection_id")
        batch_op.create_index("ix_changes_inspection_id_seq", ["inspection_id", "seq"])
    op.create_table(
        "sync_receipts",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("user_id", sa.Integer(), nullable=False),
        sa.Column("client_id", sa.String(length=64), nullable=False),
        sa.Column("defect_id", sa.Integer(), nullable=False),
        sa.Column("request_sha256", sa.String(length=64), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("revision", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["user_id"],
            ["users.id"],
            name=op.f("fk_sync_receipts_user_id_users"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["defect_id"],
            ["defects.id"],
            name=op.f("fk_sync_receipts_defect_id_defects"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_sync_receipts")),
        sa.UniqueConstraint(
            "user_id", "client_id", name=op.f("uq_sync_receipts_user_id_client_id")
        ),
    )
    with op.batch_alter_table("sync_receipts", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_sync_receipts_defect_id"), ["defect_id"], unique=False)


def downgrade() -> None:
    with op.batch_alter_table("sync_receipts", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_sync_receipts_defect_id"))
    op.drop_table("sync_receipts")
    with op.batch_alter_table("changes", schema=None) as batch_op:
        batch_op.drop_index("ix_changes_inspection_id_seq")
        batch_op.create_index("ix_changes_inspection_id", ["inspection_id"])
    with op.batch_alter_table("inspections", schema=None) as batch_op:
        batch_op.drop_column("markers")
    with op.batch_alter_table("judgment_revisions", schema=None) as batch_op:
        batch_op.drop_column("client_time")
    with op.batch_alter_table("judgments", schema=None) as batch_op:
        batch_op.drop_column("client_time")
