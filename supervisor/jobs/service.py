"""Runs and jobs: creating a run's job graph, reading it, cancelling and retrying."""

from __future__ import annotations

from pydantic import BaseModel, ValidationError
from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session

from contract.kinds import JobKind
from supervisor.audit.service import Actor, audit
from supervisor.changes import record_change, record_update
from supervisor.engine.dispatch import Dispatch
from supervisor.engine.graph import cancel_dependents, dependencies, dependents
from supervisor.engine.registry import all_kinds, get_kind
from supervisor.inspections.service import ensure_live, follow_runs
from supervisor.jobs.schemas import JobOut, RunCreate, RunOut
from supervisor.jobs.step_inputs import check_step_inputs
from supervisor.models import Artifact, Job, JobDependency, Run
from supervisor.models._types import utcnow
from supervisor.models.jobs import FINISHED
from supervisor.problems import Problem, issue_sentence, not_found

RUN_STATUS_ORDER = ("failed", "running", "queued", "waiting", "cancelled", "succeeded")


def create_run(
    session: Session, *, inspection_id: int, data: RunCreate, actor: Actor, max_attempts: int
) -> tuple[Run, list[Dispatch]]:
    """Validate the steps and add the run with one job per step; returns what to send."""
    names = [step.name for step in data.steps]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise Problem(422, f"Step names must be unique within a run; repeated: {duplicates}.")
    wanted_inputs = {i for step in data.steps for i in step.inputs}
    artifact_kinds = dict(
        session.execute(
            select(Artifact.id, Artifact.kind).where(
                Artifact.id.in_(wanted_inputs), Artifact.inspection_id == inspection_id
            )
        ).all()
    )
    kinds: dict[str, tuple[JobKind, BaseModel]] = {}
    for index, step in enumerate(data.steps):
        kind = get_kind(step.kind)
        if kind is None:
            raise Problem(422, f"steps[{index}].kind: there is no job kind {step.kind!r}.")
        try:
            kinds[step.name] = (kind, kind.params.model_validate(step.params))
        except ValidationError as exc:
            where = ("steps", index, "params")
            raise Problem(422, issue_sentence(exc.errors()[0], where) + ".") from exc
        missing = sorted(set(step.inputs) - set(artifact_kinds))
        if missing:
            raise Problem(
                422, f"steps[{index}].inputs: no artifacts {missing} in inspection {inspection_id}."
            )
        earlier = names[:index]
        for dependency in step.after:
            if dependency not in earlier:
                raise Problem(
                    422, f"steps[{index}].after: {dependency!r} is not an earlier step of this run."
                )
        check_step_inputs(
            f"steps[{index}] ({step.name})",
            kind,
            given={i: artifact_kinds[i] for i in sorted(set(step.inputs))},
            upstream={name: kinds[name][0] for name in dict.fromkeys(step.after)},
            producers=all_kinds(),
            params=kinds[step.name][1].model_dump(mode="json"),
        )

    run = Run(inspection_id=inspection_id, name=data.name, created_by=actor.id)
    session.add(run)
    session.flush()
    jobs_by_name: dict[str, Job] = {}
    for position, step in enumerate(data.steps):
        kind, params = kinds[step.name]
        job = Job(
            run_id=run.id,
            inspection_id=inspection_id,
            step=step.name,
            position=position,
            kind=kind.name,
            queue=kind.queue,
            params=params.model_dump(mode="json"),
            input_artifact_ids=sorted(set(step.inputs)),
            status="waiting" if step.after else "queued",
            progress=0.0,
            message="waiting for " + ", ".join(step.after) if step.after else "queued",
            attempts=0,
            max_attempts=max_attempts,
            cancel_requested=False,
        )
        session.add(job)
        session.flush()
        jobs_by_name[step.name] = job
        for dependency in dict.fromkeys(step.after):
            session.add(JobDependency(job_id=job.id, depends_on_id=jobs_by_name[dependency].id))
        record_change(
            session,
            entity="job",
            entity_id=job.id,
            op="create",
            inspection_id=inspection_id,
            user_id=actor.id,
        )
    record_change(
        session,
        entity="run",
        entity_id=run.id,
        op="create",
        inspection_id=inspection_id,
        user_id=actor.id,
    )
    audit(
        session,
        actor,
        "create",
        entity="run",
        entity_id=run.id,
        inspection_id=inspection_id,
        after={"steps": [{"name": s.name, "kind": s.kind} for s in data.steps]},
    )
    session.flush()
    follow_runs(session, inspection_id=inspection_id)
    ready = [Dispatch(j.id, j.queue) for j in jobs_by_name.values() if j.status == "queued"]
    return run, ready


def jobs_out(session: Session, jobs: list[Job]) -> list[JobOut]:
    edges = dependencies(session, [j.id for j in jobs])
    return [
        JobOut.model_validate(job).model_copy(update={"depends_on": edges.get(job.id, [])})
        for job in jobs
    ]


def job_out(session: Session, job: Job) -> JobOut:
    return jobs_out(session, [job])[0]


def run_status(statuses: list[str]) -> str:
    present = set(statuses)
    if present <= {"succeeded"}:
        return "succeeded"
    if "failed" in present:
        return "failed"
    if "running" in present or ("succeeded" in present and present & {"queued", "waiting"}):
        return "running"
    return next(s for s in RUN_STATUS_ORDER if s in present)


def run_out(session: Session, run: Run) -> RunOut:
    jobs = session.scalars(select(Job).where(Job.run_id == run.id).order_by(Job.position)).all()
    outs = jobs_out(session, list(jobs))
    return RunOut(
        id=run.id,
        inspection_id=run.inspection_id,
        name=run.name,
        status=run_status([j.status for j in jobs]),  # type: ignore[arg-type]
        progress=sum(j.progress for j in jobs) / len(jobs) if jobs else 0.0,
        created_by=run.created_by,
        created_at=run.created_at,
        jobs=outs,
    )


def get_run(session: Session, *, run_id: int) -> Run:
    run = session.get(Run, run_id)
    if run is None:
        raise not_found("run", run_id)
    ensure_live(session, run.inspection_id, "run", run_id)
    return run


def input_artifacts(session: Session, job: Job) -> list[Artifact]:
    """What a job reads: the artifacts its step named and its predecessors' outputs."""
    upstream = select(JobDependency.depends_on_id).where(JobDependency.job_id == job.id)
    return list(
        session.scalars(
            select(Artifact)
            .where(
                or_(Artifact.id.in_(job.input_artifact_ids or []), Artifact.job_id.in_(upstream))
            )
            .order_by(Artifact.id)
        ).all()
    )


def get_job(session: Session, *, job_id: int) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise not_found("job", job_id)
    ensure_live(session, job.inspection_id, "job", job_id)
    return job


def _audit_job(session: Session, actor: Actor, action: str, job: Job, before: str) -> None:
    audit(
        session,
        actor,
        action,
        entity="job",
        entity_id=job.id,
        inspection_id=job.inspection_id,
        before={"status": before},
        after={"status": job.status},
    )


def cancel_job(session: Session, *, job_id: int, actor: Actor) -> Job:
    """Cancel now if not started; ask the worker to stop if running (it ends soon after)."""
    job = get_job(session, job_id=job_id)
    before = job.status
    if job.status in FINISHED:
        raise Problem(409, f"Job {job_id} already {job.status}; there is nothing to cancel.")
    if job.status == "running":
        session.execute(
            update(Job)
            .where(Job.id == job_id, Job.status == "running")
            .values(cancel_requested=True, message="cancellation requested")
        )
    else:
        job.status = "cancelled"
        job.message = "cancelled before it started"
        job.finished_at = utcnow()
        cancel_dependents(session, job.id, f"not run: step '{job.step}' (job {job.id}) cancelled")
        session.flush()
        follow_runs(session, inspection_id=job.inspection_id)
    record_update(session, "job", job, user_id=actor.id)
    session.flush()
    session.refresh(job)
    _audit_job(session, actor, "cancel", job, before)
    return job


def retry_job(session: Session, *, job_id: int, actor: Actor) -> tuple[Job, list[Dispatch]]:
    """Run a failed or cancelled job again, with the jobs downstream of it."""
    job = get_job(session, job_id=job_id)
    before = job.status
    if job.status not in ("failed", "cancelled"):
        raise Problem(
            409, f"Job {job_id} is {job.status}; only failed or cancelled jobs are retried."
        )
    ready = []
    frontier = [job.id]
    while frontier:
        current = session.scalars(select(Job).where(Job.id.in_(frontier))).all()
        frontier = []
        for item in current:
            if item.id != job.id and item.status not in ("cancelled", "failed"):
                continue
            upstream = dependencies(session, [item.id]).get(item.id, [])
            unfinished = session.scalars(
                select(Job.id).where(Job.id.in_(upstream), Job.status != "succeeded")
            ).all()
            item.status = "waiting" if unfinished else "queued"
            item.attempts = 0
            item.progress = 0.0
            item.error = None
            item.result = None
            item.cancel_requested = False
            item.not_before = None
            item.dispatched_at = None
            item.finished_at = None
            item.message = "retry requested"
            record_update(session, "job", item, user_id=actor.id)
            if item.status == "queued":
                ready.append(Dispatch(item.id, item.queue))
            frontier.extend(dependents(session, [item.id]))
    session.flush()
    follow_runs(session, inspection_id=job.inspection_id)
    _audit_job(session, actor, "retry", job, before)
    return job, ready
