"""The engine's one port to the domains it serves.

The engine claims, runs and ends jobs; what a job's inputs are, how its outputs become
artifacts and findings, and what an inspection's status does when a job ends are the
domains' to say. They say it through ``JobRecords``, handed to the engine in its
``Runtime`` by whoever assembles the process (``supervisor.app``, ``supervisor.worker_app``):
the engine imports no domain's service module, and the domains import only the engine's
public modules (registry, runtime, dispatch, graph, transient and this one).

Every method runs inside the engine's transaction (``session``): a job's outputs, its
findings and its status commit together or not at all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from sqlalchemy.orm import Session

from contract.context import NewDefect
from supervisor.models import Artifact, Job
from supervisor.storage import StoredFile


@dataclass(frozen=True)
class StagedArtifact:
    """A file a handler wrote, already in its final place in storage, not yet recorded."""

    kind: str
    name: str
    media_type: str
    stored: StoredFile
    meta: dict


@dataclass(frozen=True)
class JobOutputs:
    """What one successful attempt leaves: its files and its findings."""

    job_id: int
    inspection_id: int
    run_id: int | None
    artifacts: Sequence[StagedArtifact]
    findings: Sequence[NewDefect]


class JobRecords(Protocol):
    """What the engine asks of the domains, in its own transaction."""

    def inputs(self, session: Session, job: Job) -> Sequence[Artifact]:
        """The artifacts ``job`` reads: those its step named and its predecessors' outputs."""

    def record_outputs(self, session: Session, outputs: JobOutputs) -> None:
        """Record a successful attempt's artifacts and findings (and what they end)."""

    def job_ended(self, session: Session, *, inspection_id: int) -> None:
        """A job of ``inspection_id`` changed status: bring what follows from it along."""
