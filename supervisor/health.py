"""Liveness and readiness."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import text

from supervisor.deps import get_runtime
from supervisor.engine.runtime import Runtime
from supervisor.problems import problem_response
from supervisor.requests import JsonGuardRoute

router = APIRouter(route_class=JsonGuardRoute, tags=["health"])


@router.get("/healthz")
def healthz() -> dict:
    """The process is alive."""
    return {"status": "ok"}


def _check_database(runtime: Runtime) -> str | None:
    try:
        with runtime.db.read() as session:
            session.execute(text("SELECT 1"))
    except Exception as exc:  # reported to the caller
        return f"database unreachable: {type(exc).__name__}"
    return None


def _check_broker(runtime: Runtime) -> str | None:
    url = runtime.settings.broker_url
    if not url:
        return None
    try:
        if url.startswith(("redis://", "rediss://", "unix://")):
            import redis

            redis.Redis.from_url(url, socket_timeout=2, socket_connect_timeout=2).ping()
        else:
            import pika

            parameters = pika.URLParameters(url)
            parameters.socket_timeout = 2
            pika.BlockingConnection(parameters).close()
    except Exception as exc:  # reported to the caller
        return f"broker unreachable: {type(exc).__name__}"
    return None


@router.get("/readyz", responses={503: {"description": "Database or broker unreachable"}})
async def readyz(runtime: Runtime = Depends(get_runtime)):  # noqa: ANN201
    """The database (and the broker, when one is configured) answer."""
    problems = [
        p
        for p in (
            await run_in_threadpool(_check_database, runtime),
            await run_in_threadpool(_check_broker, runtime),
        )
        if p
    ]
    if problems:
        return problem_response(503, "Not ready: " + "; ".join(problems) + ".", instance="/readyz")
    engine = "dramatiq" if runtime.settings.broker_url else "embedded"
    return {"status": "ready", "database": runtime.db.engine.dialect.name, "engine": engine}
