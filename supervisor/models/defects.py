"""Defects found by jobs (or reported by hand) and the judgments of reviewers."""

from __future__ import annotations

from datetime import datetime
from typing import Literal, get_args

from sqlalchemy import CheckConstraint, Float, ForeignKey, Integer, String, Text, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from contract.vocabulary import DEFECT_TYPES, SEVERITIES
from supervisor.db import Base
from supervisor.models._types import JSONType, UTCDateTime, created_at_column, utcnow

DefectStatus = Literal["open", "resolved", "dismissed"]
Ended = Literal["superseded", "not found again"]
"""Why a job's finding is no longer current: a later measurement of its area found it
again (its successor carries its judgments) or did not find it."""
Verdict = Literal["confirmed", "rejected", "reclassified", "uncertain"]
DEFECT_STATUSES: tuple[DefectStatus, ...] = get_args(DefectStatus)
ENDINGS: tuple[Ended, ...] = get_args(Ended)
VERDICTS: tuple[Verdict, ...] = get_args(Verdict)


class Defect(Base):
    __tablename__ = "defects"
    __table_args__ = (
        CheckConstraint(f"type IN {DEFECT_TYPES}", name="type"),
        CheckConstraint(f"status IN {DEFECT_STATUSES}", name="status"),
        CheckConstraint(f"severity IN {SEVERITIES}", name="severity"),
        CheckConstraint("confidence >= 0 AND confidence <= 1", name="confidence"),
        CheckConstraint(f"ended IN {ENDINGS}", name="ended"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    inspection_id: Mapped[int] = mapped_column(
        ForeignKey("inspections.id", ondelete="CASCADE"), index=True
    )
    run_id: Mapped[int | None] = mapped_column(
        ForeignKey("runs.id", ondelete="SET NULL"), index=True
    )
    job_id: Mapped[int | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"))
    type: Mapped[str] = mapped_column(String(16), index=True)
    status: Mapped[str] = mapped_column(String(16), default="open", index=True)
    value_mm: Mapped[float | None] = mapped_column(Float)
    tolerance_mm: Mapped[float | None] = mapped_column(Float)
    measurements: Mapped[dict] = mapped_column(JSONType, default=dict)
    location_mm: Mapped[list] = mapped_column(JSONType)
    normal: Mapped[list] = mapped_column(JSONType)
    extent_mm: Mapped[float] = mapped_column(Float, default=0.0)
    severity: Mapped[str] = mapped_column(String(16), default="minor")
    confidence: Mapped[float] = mapped_column(Float, default=1.0)
    source: Mapped[str] = mapped_column(String(16), default="job")
    status_by: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    """Who last set the status (resolved or dismissed it, or reopened it)."""
    status_reason: Mapped[str] = mapped_column(Text, default="")
    """Why, in their words (required to dismiss)."""
    lineage_id: Mapped[int | None] = mapped_column(Integer, index=True)
    """The first finding of its line: every measurement of one physical defect shares it
    (None until set, right after the row is made: its own id)."""
    supersedes_id: Mapped[int | None] = mapped_column(ForeignKey("defects.id", ondelete="SET NULL"))
    """The previous measurement's finding this one continues."""
    superseded_by_id: Mapped[int | None] = mapped_column(
        ForeignKey("defects.id", ondelete="SET NULL")
    )
    ended: Mapped[str | None] = mapped_column(String(16), index=True)
    """None while current; else why not (``Ended``)."""
    ended_run_id: Mapped[int | None] = mapped_column(ForeignKey("runs.id", ondelete="SET NULL"))
    """The run whose measurement superseded it or did not find it again."""
    notes: Mapped[list] = mapped_column(JSONType, default=list)
    """What people noted about it, oldest first: ``{user_id, username, text, at}``."""
    created_at: Mapped[datetime] = created_at_column()


class Judgment(Base):
    """The current judgment of one user on one defect; ``revision`` counts its edits."""

    __tablename__ = "judgments"
    __table_args__ = (
        UniqueConstraint("defect_id", "user_id"),
        CheckConstraint(f"verdict IN {VERDICTS}", name="verdict"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    defect_id: Mapped[int] = mapped_column(ForeignKey("defects.id", ondelete="CASCADE"), index=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    verdict: Mapped[str] = mapped_column(String(16))
    new_type: Mapped[str | None] = mapped_column(String(16))
    comment: Mapped[str] = mapped_column(Text, default="")
    revision: Mapped[int] = mapped_column(Integer, default=1)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    client_time: Mapped[datetime | None] = mapped_column(UTCDateTime())
    """When the judging client made this version: a headset's clock for offline edits, the
    server's for edits over the API. A user's newest version by this time wins."""
    judged_on_run_id: Mapped[int | None] = mapped_column(Integer)
    """The run whose finding the user judged, where that is an earlier measurement of this
    one (the judgment was carried over, or sent for a finding since superseded); None:
    judged on this finding itself."""


class JudgmentRevision(Base):
    """Every version a judgment ever had, in order."""

    __tablename__ = "judgment_revisions"
    __table_args__ = (UniqueConstraint("defect_id", "user_id", "revision"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    defect_id: Mapped[int] = mapped_column(ForeignKey("defects.id", ondelete="CASCADE"), index=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    revision: Mapped[int] = mapped_column(Integer)
    verdict: Mapped[str] = mapped_column(String(16))
    new_type: Mapped[str | None] = mapped_column(String(16))
    comment: Mapped[str] = mapped_column(Text, default="")
    client_time: Mapped[datetime | None] = mapped_column(UTCDateTime())
    judged_on_run_id: Mapped[int | None] = mapped_column(Integer)
    created_at: Mapped[datetime] = created_at_column()


class SyncReceipt(Base):
    """The outcome of one offline judgment a client sent, by its client-generated id, so
    that a retried batch gets the same answer and changes nothing."""

    __tablename__ = "sync_receipts"
    __table_args__ = (UniqueConstraint("user_id", "client_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    client_id: Mapped[str] = mapped_column(String(64))
    defect_id: Mapped[int] = mapped_column(ForeignKey("defects.id", ondelete="CASCADE"), index=True)
    request_sha256: Mapped[str] = mapped_column(String(64))
    status: Mapped[str] = mapped_column(String(16))
    revision: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = created_at_column()
