"""Inspections and the artifacts (files) that belong to them."""

from __future__ import annotations

from datetime import datetime
from typing import Literal, get_args

from sqlalchemy import BigInteger, CheckConstraint, ForeignKey, Integer, String
from sqlalchemy.orm import Mapped, mapped_column

from supervisor.db import Base
from supervisor.models._types import JSONType, UTCDateTime, created_at_column, utcnow

AREA_SUGGESTIONS = ("cabin", "cargo", "component", "wing", "fuselage", "vehicle", "street drive")
"""What a new inspection's area is often called: suggestions, not a list to pick from."""
InspectionStatus = Literal["planned", "scanning", "processing", "review", "closed"]
INSPECTION_STATUSES: tuple[InspectionStatus, ...] = get_args(InspectionStatus)


class Inspection(Base):
    __tablename__ = "inspections"
    __table_args__ = (CheckConstraint(f"status IN {INSPECTION_STATUSES}", name="status"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    title: Mapped[str] = mapped_column(String(200))
    aircraft: Mapped[str] = mapped_column(String(100), default="")
    serial: Mapped[str] = mapped_column(String(100), default="")
    area: Mapped[str] = mapped_column(String(64))
    """Free text: what is inspected (a cabin, a wing's flap, a street drive)."""
    tolerances: Mapped[dict] = mapped_column(JSONType, default=dict)
    tolerance_set: Mapped[dict | None] = mapped_column(JSONType)
    """The named tolerance set last applied: its id, name and version then, and whether a
    limit was edited by hand since."""
    markers: Mapped[list] = mapped_column(JSONType, default=list)
    """Image markers at known poses (cargo, cabin) that align a headset with the scene."""
    status: Mapped[str] = mapped_column(String(16), default="planned")
    created_by: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    """The owner: with admins, the only one who may delete or close it or change its
    tolerances."""
    created_at: Mapped[datetime] = created_at_column()
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow, onupdate=utcnow)
    deleted_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), index=True)
    """Set when it went to the trash: hidden everywhere, restorable, files kept until purged."""
    deleted_by: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))


class Artifact(Base):
    __tablename__ = "artifacts"

    id: Mapped[int] = mapped_column(primary_key=True)
    inspection_id: Mapped[int] = mapped_column(
        ForeignKey("inspections.id", ondelete="CASCADE"), index=True
    )
    kind: Mapped[str] = mapped_column(String(32))
    name: Mapped[str] = mapped_column(String(255))
    media_type: Mapped[str] = mapped_column(String(100))
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    sha256: Mapped[str] = mapped_column(String(64))
    storage_uri: Mapped[str] = mapped_column(String(500))
    meta: Mapped[dict] = mapped_column(JSONType, default=dict)
    job_id: Mapped[int | None] = mapped_column(
        ForeignKey("jobs.id", ondelete="SET NULL"), index=True
    )
    created_by: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = created_at_column()


class ToleranceSet(Base):
    """Named acceptance limits reusable across inspections; ``version`` counts its edits."""

    __tablename__ = "tolerance_sets"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(100), unique=True)
    description: Mapped[str] = mapped_column(String(2000), default="")
    tolerances: Mapped[dict] = mapped_column(JSONType, default=dict)
    version: Mapped[int] = mapped_column(Integer, default=1)
    created_by: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = created_at_column()
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow, onupdate=utcnow)
