"""ORM models, one module per table family; importing this registers them all."""

from supervisor.models.changes import Change, IdempotencyRecord
from supervisor.models.defects import Defect, Judgment, JudgmentRevision, SyncReceipt
from supervisor.models.inspections import Artifact, Inspection
from supervisor.models.jobs import Job, JobDependency, Run
from supervisor.models.users import ApiToken, User

__all__ = [
    "ApiToken",
    "Artifact",
    "Change",
    "Defect",
    "IdempotencyRecord",
    "Inspection",
    "Job",
    "JobDependency",
    "Judgment",
    "JudgmentRevision",
    "Run",
    "SyncReceipt",
    "User",
]
