"""Headset sync: pull what changed since a cursor, push judgments made offline."""

from __future__ import annotations

import gzip

import orjson
from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from supervisor.deps import JUDGE_ROLES, READ_ROLES, CurrentUser, get_runtime, require
from supervisor.engine.runtime import Runtime
from supervisor.ids import MAX_ID
from supervisor.requests import JsonGuardRoute
from supervisor.sync import service
from supervisor.sync.schemas import BatchOut, JudgmentBatch, SyncOut

router = APIRouter(route_class=JsonGuardRoute, tags=["sync"])
readers = require(*READ_ROLES, action="sync inspections")
judges = require(*JUDGE_ROLES, action="judge defects")
GZIP_MIN_BYTES = 1400


def _json(document: dict, request: Request) -> Response:
    """JSON, gzip-compressed when the client accepts it and it is worth it."""
    body = orjson.dumps(document)
    headers = {"Vary": "Accept-Encoding"}
    if len(body) >= GZIP_MIN_BYTES and "gzip" in request.headers.get("accept-encoding", ""):
        body = gzip.compress(body, compresslevel=5, mtime=0)
        headers["Content-Encoding"] = "gzip"
    return Response(body, media_type="application/json", headers=headers)


@router.get("/sync", response_model=SyncOut)
async def sync(
    request: Request,
    inspection: int = Query(ge=1, le=MAX_ID, description="The inspection to sync."),
    since: str | None = Query(
        None,
        description="The `next_cursor` of the last sync of this inspection (another is "
        "refused: 400); none or `0` for everything.",
    ),
    limit: int = Query(
        service.DEFAULT_PAGE,
        ge=1,
        le=service.MAX_PAGE,
        description="Most defects (full sync) or log entries (after a cursor) per page.",
    ),
    runtime: Runtime = Depends(get_runtime),
    _: CurrentUser = Depends(readers),
) -> Response:
    """Everything that changed in an inspection since a cursor: defects (their state now),
    judgments, the consensus of every defect whose judgments changed, the scene's ETag and
    the next cursor. Without a cursor: the whole inspection, in pages of `limit` defects
    (`more` says another page waits). Clients upsert by id; an entity may come twice.
    An inspection deleted since the cursor answers 410: drop the local copy."""
    cursor = service.decode_cursor(since, inspection)

    def read() -> dict:
        with runtime.db.read() as session:
            return service.changes_since(
                session,
                inspection_id=inspection,
                cursor=cursor,
                limit=limit,
                scene_points=runtime.settings.scene_max_points,
            )

    return _json(await run_in_threadpool(read), request)


@router.post("/sync/judgments", response_model=BatchOut)
async def push_judgments(
    body: JudgmentBatch,
    request: Request,
    runtime: Runtime = Depends(get_runtime),
    user: CurrentUser = Depends(judges),
) -> Response:
    """Judgments made offline, in one batch (at most 1000). Each item has a client-made
    `client_id` and the `client_time` it was made: a retried item is answered as the first
    time and changes nothing; a user's judgment of a defect is the one with the latest
    client time, whichever device sent it and when. One result per item, in order."""
    results, consensus = await run_in_threadpool(
        service.apply_batch, runtime.db, user_id=user.id, username=user.username, items=body.items
    )
    return _json({"results": results, "consensus": consensus}, request)
