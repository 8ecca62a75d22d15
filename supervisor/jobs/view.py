"""A job's run page: the job, its inputs and outputs, and its results drawn as the job's
kind declares (``JobKind.shows.page``, a ``contract.views.View`` hook called on the stored
outputs). A hook that cannot read a file says so in ``note``: the page still lists the
files."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime

from pydantic import BaseModel, ConfigDict
from sqlalchemy import select
from sqlalchemy.orm import Session

from contract.views import JobFiles, Panel, Pictures, result_view
from supervisor.artifacts.schemas import ArtifactOut
from supervisor.engine.registry import get_kind
from supervisor.jobs.schemas import JobOut
from supervisor.jobs.service import get_job, input_artifacts, job_out
from supervisor.models import Artifact, Job, JobLogLine
from supervisor.storage import Storage

LOG_LINES = 500


class LogLine(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    attempt: int
    at: datetime
    progress: float
    message: str


class JobViewOut(BaseModel):
    job: JobOut
    inputs: list[ArtifactOut]
    """The artifacts the job was given (a later step's also reads its predecessors' outputs)."""
    outputs: list[ArtifactOut]
    panels: list[Panel]
    """The results as the kind draws them (empty until the job has succeeded)."""
    note: str | None = None
    """Why no panels are shown, when that is not plain from the job's status."""
    scene: str | None = None
    """Its 3D scene's URL (glTF), when its kind has one and it succeeded."""
    log: list[LogLine] = []
    """Its progress messages, oldest first (its last ``LOG_LINES``, every attempt)."""


def job_files(
    session: Session, storage: Storage, job: Job
) -> tuple[list[Artifact], list[Artifact], JobFiles]:
    """The job's input and output artifacts, and what its kind's hooks read of them."""
    outputs = session.scalars(
        select(Artifact).where(Artifact.job_id == job.id).order_by(Artifact.id)
    ).all()
    given = input_artifacts(session, job)
    files = JobFiles(
        job.result or {},
        {a.name: storage.path(a.storage_uri) for a in outputs},
        {f"{a.kind}/{a.name}": storage.path(a.storage_uri) for a in given},
    )
    return list(given), list(outputs), files


def job_view(session: Session, storage: Storage, job_id: int) -> JobViewOut:
    job = get_job(session, job_id=job_id)
    given, outputs, files = job_files(session, storage, job)
    panels, note = [], None
    kind = get_kind(job.kind)
    view = kind.shows.load_page() if kind is not None else None
    if view is None:
        view = result_view
        note = "this kind of job declares no view of its results: its result's figures and its files are shown"
    if job.status == "succeeded":
        try:
            panels = view(files)
        except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
            note = f"the results could not be drawn ({type(exc).__name__}: {exc}); the files are listed"
        ids = {f"{a.kind}/{a.name}": a.id for a in given} | {a.name: a.id for a in outputs}
        panels = [_with_ids(p, ids) for p in panels]
    return JobViewOut(
        job=job_out(session, job),
        inputs=[ArtifactOut.model_validate(a) for a in given],
        outputs=[ArtifactOut.model_validate(a) for a in outputs],
        panels=panels,
        note=note,
        log=_log(session, job.id),
        scene=(
            f"/api/v1/jobs/{job.id}/scene.glb"
            if kind is not None and kind.shows.scene is not None and job.status == "succeeded"
            else None
        ),
    )


def _log(session: Session, job_id: int) -> list[JobLogLine]:
    newest = session.scalars(
        select(JobLogLine)
        .where(JobLogLine.job_id == job_id)
        .order_by(JobLogLine.id.desc())
        .limit(LOG_LINES)
    ).all()
    return newest[::-1]


def _with_ids(panel, ids: dict[str, int]):  # noqa: ANN001, ANN202 - a contract.views panel
    """Pictures name their layers by file (an output's name, an input's ``kind/name``): the
    stored artifact of each (0: none)."""
    if not isinstance(panel, Pictures):
        return panel
    pictures = [
        replace(p, artifact_ids=[ids.get(name, 0) for name in p.layers]) for p in panel.pictures
    ]
    return replace(panel, pictures=pictures)
