"""The domains' side of the engine's port (``supervisor.engine.port.JobRecords``): a job's
inputs are the jobs service's to find, its outputs become rows through the one write path
of artifacts and of defects, and an inspection's status follows its runs."""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy.orm import Session

from supervisor.artifacts.service import record_artifact
from supervisor.defects.lineage import supersede
from supervisor.defects.service import record_defects
from supervisor.engine.port import JobOutputs
from supervisor.inspections.service import follow_runs
from supervisor.jobs.service import input_artifacts
from supervisor.models import Artifact, Job


class DomainRecords:
    """``JobRecords`` for vista's domains. Stateless, so a worker process can be handed it."""

    def inputs(self, session: Session, job: Job) -> Sequence[Artifact]:
        return input_artifacts(session, job)

    def record_outputs(self, session: Session, outputs: JobOutputs) -> None:
        for staged in outputs.artifacts:
            record_artifact(
                session,
                inspection_id=outputs.inspection_id,
                kind=staged.kind,
                name=staged.name,
                media_type=staged.media_type,
                stored=staged.stored,
                meta=staged.meta,
                job_id=outputs.job_id,
            )
        record_defects(
            session,
            outputs.findings,
            inspection_id=outputs.inspection_id,
            source="job",
            run_id=outputs.run_id,
            job_id=outputs.job_id,
        )
        supersede(session, job_id=outputs.job_id)

    def job_ended(self, session: Session, *, inspection_id: int) -> None:
        follow_runs(session, inspection_id=inspection_id)
