"""The base of every request body the API reads, and the guard every JSON body passes."""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from typing import Annotated, Any

import numpy as np
from fastapi import Request, Response
from fastapi.routing import APIRoute
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field
from pydantic_core import PydanticCustomError

from supervisor.ids import MAX_ID

MAX_MM = 1e6
"""A kilometre: no coordinate or length the API keeps is larger."""
Millimetres = Annotated[float, Field(ge=-MAX_MM, le=MAX_MM)]


def _json_number(value: object) -> object:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise PydanticCustomError("int_type", "Input should be a valid integer")
    return value


RequestId = Annotated[int, Field(strict=False, ge=1, le=MAX_ID), BeforeValidator(_json_number)]
"""A row id in a request body: an integer as JSON Schema has it — 3 or 3.0, not 3.5, "3"
or true (a strict int would refuse 3.0, a lax one take "3" and true)."""


class RequestModel(BaseModel):
    """Unknown fields are refused, and so are numbers that are not finite: NaN, ±Infinity
    and literals beyond a double's range (``1e400``, which JSON parsers read as infinity)
    — each with a 422 naming the field, before anything is stored.

    Types are strict, as the schema states them: no ``"5"`` or ``true`` for a number, no
    ``1`` or ``"yes"`` for a boolean, no number for a string. (A field whose JSON value
    becomes another Python type — an array a tuple, a string a datetime — says
    ``strict=False``, and checks the JSON value first where lax parsing would take more
    than the schema allows: ``RequestId``, ``OfflineJudgment.client_time``.)"""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


def _no_default(schema: dict[str, Any]) -> None:
    schema.pop("default", None)


def omittable(**constraints: Any) -> Any:
    """A field that may be left out (it is None then) but not given as null: a PATCH's
    field that has no "empty" value."""
    return Field(None, json_schema_extra=_no_default, **constraints)


MAX_JSON_BODY_BYTES = 16 << 20
"""The largest JSON request body (a headset's batch of offline judgments is the largest:
kilobytes a judgment)."""
MAX_JSON_BODY_DEPTH = 32
"""The deepest nesting of arrays and objects in a JSON request body: the API's documents
nest a few levels (a run's step's params, a tolerance document), and a body 256 levels
deep reached the idempotency digest's serialiser, which refused it with a 500."""


class JsonGuardRoute(APIRoute):
    """A route whose JSON body is measured before anything reads it — the size, then the
    nesting (``archive.json_depth``: without parsing) — and refused with a 413 or a 422
    naming the limit. One guard for every body the API parses; routes without a body
    model (an upload, read as its raw stream) are left alone."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        if self.body_field is None:
            return handler

        async def guarded(request: Request) -> Response:
            await _check_json_body(request)
            return await handler(request)

        return guarded


async def _check_json_body(request: Request) -> None:
    from services.lib.archive import json_depth
    from supervisor.problems import Problem

    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > MAX_JSON_BODY_BYTES:
        raise Problem(413, _too_large())
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_JSON_BODY_BYTES:
            raise Problem(413, _too_large())
        chunks.append(chunk)
    body = b"".join(chunks)
    request._body = body  # what the route's own parsing reads
    media_type = request.headers.get("content-type", "application/json").split(";")[0]
    if not media_type.strip().lower().endswith("json"):
        return  # a form (a sign-in's password may hold any brackets)
    if json_depth(np.frombuffer(body, np.uint8), stop_above=MAX_JSON_BODY_DEPTH) > (
        MAX_JSON_BODY_DEPTH
    ):
        raise Problem(
            422,
            f"The JSON body nests arrays or objects more than {MAX_JSON_BODY_DEPTH} levels "
            "deep; the API's documents need a few.",
        )


def _too_large() -> str:
    return f"The JSON body is larger than {MAX_JSON_BODY_BYTES >> 20} MiB."
