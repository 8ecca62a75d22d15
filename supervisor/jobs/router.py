"""Runs (the processing timeline of an inspection) and their jobs."""

from __future__ import annotations

import asyncio
import json
from dataclasses import asdict

from fastapi import APIRouter, Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, StreamingResponse
from sqlalchemy import select
from sqlalchemy.orm import Session

from supervisor.db import after_commit
from supervisor.deps import EDIT_ROLES, READ_ROLES, SESSION, CurrentUser, get_runtime, require
from supervisor.engine.dispatch import dispatch
from supervisor.engine.registry import load_kinds
from supervisor.engine.runtime import Runtime
from supervisor.idempotency import create_once, digest_model
from supervisor.ids import IdPath, IdQuery
from supervisor.inspections.service import get as get_inspection
from supervisor.inspections.service import live
from supervisor.jobs import service
from supervisor.jobs.schemas import (
    InputsOut,
    JobKindOut,
    JobOut,
    JobStatus,
    OutputOut,
    RunCreate,
    RunOut,
)
from supervisor.jobs.view import JobViewOut, job_view
from supervisor.models import Job, Run
from supervisor.models.jobs import FINISHED
from supervisor.pagination import DEFAULT_LIMIT, Limit, Page, paginate
from supervisor.problems import Problem
from supervisor.requests import JsonGuardRoute

router = APIRouter(route_class=JsonGuardRoute, tags=["runs and jobs"])
readers = require(*READ_ROLES, action="read runs and jobs")
operators = require(*EDIT_ROLES, action="start, cancel or retry jobs")
EVENT_POLL_S = 0.5
EVENT_KEEPALIVE_S = 15.0


@router.get("/job-kinds", response_model=list[JobKindOut])
def list_job_kinds(
    runtime: Runtime = Depends(get_runtime), _: CurrentUser = Depends(readers)
) -> list[JobKindOut]:
    """The job kinds a run's steps may use, with the JSON schema of their params."""
    kinds = load_kinds(runtime.settings.extra_job_kinds)
    return [
        JobKindOut(
            name=k.name,
            aliases=list(k.aliases),
            queue=k.queue,
            description=k.description,
            input_kinds=list(k.input_kinds),
            inputs=[InputsOut.model_validate(asdict(spec)) for spec in k.inputs],
            outputs=[OutputOut.model_validate(asdict(output)) for output in k.outputs],
            params_schema=k.params.model_json_schema(),
        )
        for k in sorted(kinds.values(), key=lambda k: k.name)
    ]


@router.post("/inspections/{inspection_id}/runs", status_code=201, response_model=RunOut)
def create_run(
    inspection_id: IdPath,
    body: RunCreate,
    request: Request,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(operators),
) -> JSONResponse:
    """Create a run from ordered steps; a step starts when the steps in its ``after`` have
    succeeded, and receives their output artifacts as inputs. Rules the schema cannot
    state (422): step names are unique; `kind` is one of GET /job-kinds and `params`
    match its `params_schema`; `inputs` are artifacts of this inspection; `after` names
    earlier steps; a step gets (from its `inputs` and its `after` steps' outputs) the
    kinds and numbers of artifacts its job kind reads."""
    get_inspection(session, inspection_id=inspection_id)
    ready = []

    def create():  # noqa: ANN202
        run, to_send = service.create_run(
            session,
            inspection_id=inspection_id,
            data=body,
            actor=user,
            max_attempts=runtime.settings.job_max_attempts,
        )
        ready.extend(to_send)
        return service.run_out(session, run).model_dump(mode="json"), f"/api/v1/runs/{run.id}"

    return create_once(
        request,
        session,
        user_id=user.id,
        body_digest=f"{inspection_id}:{digest_model(body)}",
        create=create,
        after_commit=lambda: dispatch(runtime.db, runtime.dispatcher, ready),
    )


@router.get("/inspections/{inspection_id}/runs", response_model=Page[RunOut])
def list_runs(
    inspection_id: IdPath,
    cursor: str | None = None,
    limit: Limit = 20,
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> Page[RunOut]:
    get_inspection(session, inspection_id=inspection_id)
    return paginate(
        session,
        select(Run).where(Run.inspection_id == inspection_id),
        cursor=cursor,
        limit=limit,
        item=RunOut,
        out=lambda rows: [service.run_out(session, r) for r in rows],
    )


@router.get("/runs/{run_id}", response_model=RunOut)
def get_run(
    run_id: IdPath, session: Session = SESSION, _: CurrentUser = Depends(readers)
) -> RunOut:
    return service.run_out(session, service.get_run(session, run_id=run_id))


@router.get("/jobs", response_model=Page[JobOut])
def list_jobs(
    run: int | None = IdQuery("Only this run's jobs."),
    inspection: int | None = IdQuery("Only this inspection's jobs."),
    status: JobStatus | None = None,
    cursor: str | None = None,
    limit: Limit = DEFAULT_LIMIT,
    session: Session = SESSION,
    _: CurrentUser = Depends(readers),
) -> Page[JobOut]:
    return paginate(
        session,
        select(Job).where(live(Job.inspection_id)),
        equal={Job.run_id: run, Job.inspection_id: inspection, Job.status: status},
        cursor=cursor,
        limit=limit,
        item=JobOut,
        out=lambda rows: service.jobs_out(session, rows),
    )


@router.get("/jobs/{job_id}", response_model=JobOut)
def get_job(
    job_id: IdPath, session: Session = SESSION, _: CurrentUser = Depends(readers)
) -> JobOut:
    return service.job_out(session, service.get_job(session, job_id=job_id))


@router.get("/jobs/{job_id}/view", response_model=JobViewOut)
def get_job_view(
    job_id: IdPath,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
    _: CurrentUser = Depends(readers),
) -> JobViewOut:
    """The job's run page: the job, its input and output artifacts, and its results as
    its kind draws them (figures, plots, pictures: ``contract.views``)."""
    return job_view(session, runtime.storage, job_id)


@router.post("/jobs/{job_id}/cancel", response_model=JobOut)
def cancel_job(
    job_id: IdPath, session: Session = SESSION, user: CurrentUser = Depends(operators)
) -> JobOut:
    """Cancel a job: at once if it has not started, else at its next progress report."""
    job = service.cancel_job(session, job_id=job_id, actor=user)
    return service.job_out(session, job)


@router.post("/jobs/{job_id}/retry", response_model=JobOut)
def retry_job(
    job_id: IdPath,
    session: Session = SESSION,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(operators),
) -> JobOut:
    """Run a failed or cancelled job again; the jobs after it follow when it succeeds."""
    job, ready = service.retry_job(session, job_id=job_id, actor=user)
    after_commit(session, lambda: dispatch(runtime.db, runtime.dispatcher, ready))
    return service.job_out(session, job)


def _snapshot(runtime: Runtime, job_id: int) -> dict | None:
    """The job as ``GET /jobs/{id}`` shows it, or None where that is a 404 (no such job,
    or its inspection is in the trash: a stream ends when it goes there)."""
    with runtime.db.read() as session:
        try:
            job = service.get_job(session, job_id=job_id)
        except Problem:
            return None
        return service.job_out(session, job).model_dump(mode="json")


@router.get(
    "/jobs/{job_id}/events",
    response_class=StreamingResponse,
    responses={200: {"content": {"text/event-stream": {}}}},
)
async def job_events(
    job_id: IdPath,
    request: Request,
    runtime: Runtime = Depends(get_runtime),
    _: CurrentUser = Depends(readers),
) -> StreamingResponse:
    """Server-sent events: a ``progress`` event at each change, ``end`` when it finishes."""
    first = await run_in_threadpool(_snapshot, runtime, job_id)
    if first is None:
        with runtime.db.read() as session:
            service.get_job(session, job_id=job_id)  # raises the 404 problem

    async def stream():  # noqa: ANN202
        last, idle = None, 0.0
        snapshot = first
        while True:
            if snapshot is None:
                return
            key = (
                snapshot["status"],
                snapshot["progress"],
                snapshot["message"],
                snapshot["attempts"],
            )
            if key != last:
                last, idle = key, 0.0
                yield f"event: progress\ndata: {json.dumps(snapshot)}\n\n"
            if snapshot["status"] in FINISHED:
                yield f"event: end\ndata: {json.dumps({'status': snapshot['status']})}\n\n"
                return
            if await request.is_disconnected():
                return
            await asyncio.sleep(EVENT_POLL_S)
            idle += EVENT_POLL_S
            if idle >= EVENT_KEEPALIVE_S:
                idle = 0.0
                yield ": keep-alive\n\n"
            snapshot = await run_in_threadpool(_snapshot, runtime, job_id)

    return StreamingResponse(
        stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"}
    )
