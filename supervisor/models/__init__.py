"""ORM models, one module per table family; importing this registers them all."""

from supervisor.db import Base
from supervisor.models.changes import AuditEvent, Change, IdempotencyRecord
from supervisor.models.defects import Defect, Judgment, JudgmentRevision, SyncReceipt
from supervisor.models.inspections import Artifact, Inspection, ToleranceSet
from supervisor.models.jobs import Job, JobDependency, JobLogLine, Run
from supervisor.models.users import ApiToken, User

# Ids are never reused: on SQLite a table without AUTOINCREMENT hands a deleted row's id
# to the next insert (a headset's queued verdict would land on another defect).
# PostgreSQL sequences never go back anyway.
for _table in Base.metadata.tables.values():
    if len(_table.primary_key.columns) == 1:
        _table.dialect_kwargs["sqlite_autoincrement"] = True

__all__ = [
    "ApiToken",
    "AuditEvent",
    "Artifact",
    "Change",
    "Defect",
    "IdempotencyRecord",
    "Inspection",
    "Job",
    "JobDependency",
    "JobLogLine",
    "Judgment",
    "JudgmentRevision",
    "Run",
    "ToleranceSet",
    "SyncReceipt",
    "User",
]
