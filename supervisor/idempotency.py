"""``Idempotency-Key`` on creating POSTs: a retried request gets the first response again.

The record is inserted in the same transaction as what the request creates, so either
both exist or neither does; a concurrent duplicate loses on the unique key and replays.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable

from fastapi import Request
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from supervisor.db import after_commit as run_after_commit
from supervisor.models import IdempotencyRecord
from supervisor.problems import Problem

KEY_HEADER = "Idempotency-Key"
MAX_KEY_LENGTH = 255

Created = tuple[dict, str | None]
"""The JSON body of the 201 response and its Location (or None)."""


def fingerprint(request: Request, body_digest: str) -> str:
    return hashlib.sha256(
        f"{request.method} {request.url.path}\n{body_digest}".encode()
    ).hexdigest()


def _replay(session: Session, user_id: int, key: str, request_sha256: str) -> JSONResponse | None:
    record = session.scalar(
        select(IdempotencyRecord).where(
            IdempotencyRecord.user_id == user_id, IdempotencyRecord.key == key
        )
    )
    if record is None:
        return None
    if record.request_sha256 != request_sha256:
        raise Problem(
            422,
            f"Idempotency-Key {key!r} was already used for a different request; "
            "use a new key for a new request.",
        )
    headers = {"Idempotent-Replayed": "true"}
    if record.location:
        headers["Location"] = record.location
    return JSONResponse(record.response_json, status_code=record.status_code, headers=headers)


def create_once(
    request: Request,
    session: Session,
    *,
    user_id: int,
    body_digest: str,
    create: Callable[[], Created],
    after_commit: Callable[[], None] | None = None,
) -> JSONResponse:
    """Run ``create`` (which adds rows to ``session``) and flush, honouring the key; the
    caller's commit policy commits, then runs ``after_commit``."""
    key = request.headers.get(KEY_HEADER)
    if key is not None and not (0 < len(key) <= MAX_KEY_LENGTH):
        raise Problem(400, f"{KEY_HEADER} must be 1 to {MAX_KEY_LENGTH} characters.")
    request_sha256 = fingerprint(request, body_digest)
    if key:
        replay = _replay(session, user_id, key, request_sha256)
        if replay is not None:
            return replay
    body, location = create()
    if key:
        session.add(
            IdempotencyRecord(
                user_id=user_id,
                key=key,
                request_sha256=request_sha256,
                status_code=201,
                response_json=body,
                location=location,
            )
        )
    try:
        session.flush()
    except IntegrityError:
        session.rollback()
        replay = _replay(session, user_id, key, request_sha256) if key else None
        if replay is None:
            raise
        return replay
    if after_commit is not None:
        run_after_commit(session, after_commit)
    return JSONResponse(body, status_code=201, headers={"Location": location} if location else None)


def digest_model(model) -> str:  # noqa: ANN001 - any pydantic model
    return hashlib.sha256(model.model_dump_json().encode()).hexdigest()
