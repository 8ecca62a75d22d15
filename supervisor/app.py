"""The supervisor's FastAPI application."""

from __future__ import annotations

import fcntl
import gc
import logging
from contextlib import asynccontextmanager
from pathlib import Path
from typing import IO

from fastapi import APIRouter, FastAPI
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline

from supervisor import health
from supervisor.artifacts.router import router as artifacts_router
from supervisor.audit.router import router as audit_router
from supervisor.auth.revocations import Revocations
from supervisor.auth.router import router as auth_router
from supervisor.defects.router import router as defects_router
from supervisor.deps import TokenCache
from supervisor.engine.embedded import EmbeddedPool
from supervisor.engine.maintenance import MaintenanceLoop, resend_queued
from supervisor.engine.runtime import Runtime
from supervisor.exports.router import router as exports_router
from supervisor.feedback.router import router as feedback_router
from supervisor.headers import SecurityHeaders
from supervisor.inspections.router import router as inspections_router
from supervisor.jobs.router import router as jobs_router
from supervisor.judgments.router import router as judgments_router
from supervisor.migrate import check_schema
from supervisor.openapi import install_openapi
from supervisor.problems import install_problem_handlers
from supervisor.records import DomainRecords
from supervisor.requests import JsonGuardRoute
from supervisor.settings import Settings, get_settings, secure_data_dir
from supervisor.sync.router import router as sync_router
from supervisor.tolerance_sets.router import router as tolerance_sets_router
from supervisor.users.router import router as users_router

log = logging.getLogger("vista")
API_PREFIX = "/api/v1"
WEB_DIST = Path(__file__).resolve().parent.parent / "clients" / "web" / "dist"


def _engine_lock(settings: Settings) -> IO | None:
    """The embedded pool's lock: held for life by the one API process that runs it."""
    secure_data_dir(settings)
    handle = open(settings.data_dir / "engine.lock", "w")  # noqa: SIM115 - held for life
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        return None
    return handle


def create_app(
    settings: Settings | None = None, *, runtime: Runtime | None = None, run_engine: bool = True
) -> FastAPI:
    """The API. With ``run_engine`` it also runs the job engine's background parts:
    the embedded worker pool (no broker) and the maintenance loop."""
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI):  # noqa: ANN202
        rt = runtime or Runtime.create(settings, records=DomainRecords())
        check_schema(rt.db.url)
        secure_data_dir(settings)
        app.state.runtime = rt
        pool, loop, lock = None, None, None
        if run_engine:
            if rt.dispatcher.polls_database and settings.embedded_workers > 0:
                lock = _engine_lock(settings)
                if lock is not None:  # with several API processes, one runs the pool
                    pool = EmbeddedPool(rt, settings.embedded_workers)
                    pool.start()
            resend_queued(rt, only_undispatched=False)
            loop = MaintenanceLoop(rt)
            loop.start()
        app.state.pool = pool
        # Everything built so far lives as long as the process: keep it out of the
        # collector's full passes, which otherwise stall every request for 100+ ms.
        gc.collect()
        gc.freeze()
        try:
            yield
        finally:
            if loop is not None:
                loop.stop()
            if pool is not None:
                pool.stop()
            if lock is not None:
                lock.close()
            if runtime is None:
                rt.db.dispose()

    # /docs and /redoc from assets shipped with the package (no CDN: they work offline)
    app = FastAPIOffline(
        title="vista supervisor",
        version="1.0",
        summary="Inspections, artifacts, processing runs, defects and reviewers' judgments.",
        lifespan=lifespan,
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url="/docs",
        redoc_url="/redoc",
        static_url="/docs-assets",
    )
    app.state.token_cache = TokenCache(Revocations(settings.resolved_artifact_dir))
    app.add_middleware(SecurityHeaders)
    install_problem_handlers(app)
    install_openapi(app)
    api = APIRouter(route_class=JsonGuardRoute, prefix=API_PREFIX)
    # Routes are matched in order, a regular expression each: the reviewers' hot paths
    # (a judgment PUT, a headset's sync) first saves 0.1 ms of every such request.
    for router in (
        judgments_router,
        sync_router,
        auth_router,
        users_router,
        inspections_router,
        artifacts_router,
        jobs_router,
        defects_router,
        exports_router,
        feedback_router,
        tolerance_sets_router,
        audit_router,
    ):
        api.include_router(router)
    app.include_router(api)
    app.include_router(health.router, include_in_schema=False)
    app.include_router(health.router, prefix=API_PREFIX)
    _serve_dashboard(app, settings)
    return app


def _serve_dashboard(app: FastAPI, settings: Settings) -> None:
    """The web dashboard's built files at `/` (after the API, which keeps its paths)."""
    folder = settings.web_dir or WEB_DIST
    if (folder / "index.html").exists():
        app.mount("/", StaticFiles(directory=folder, html=True), name="dashboard")
        return

    @app.get("/", include_in_schema=False)
    def dashboard_missing() -> HTMLResponse:
        return HTMLResponse(
            f"<h1>vista</h1><p>The dashboard is not built ({folder} has no index.html): run "
            "<code>make web</code>. The API is at <a href='/docs'>/docs</a>.</p>",
            status_code=503,
        )
