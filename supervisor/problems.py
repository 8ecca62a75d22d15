"""Errors as RFC 9457 problem details, each with a sentence a person can act on."""

from __future__ import annotations

import logging
from typing import Annotated, Any, NotRequired

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import Field
from starlette.exceptions import HTTPException as StarletteHTTPException
from typing_extensions import TypedDict  # pydantic reads typing.TypedDict from 3.12 only

PROBLEM_MEDIA_TYPE = "application/problem+json"
log = logging.getLogger("vista.api")

_TITLES = {
    400: "Bad request",
    401: "Not signed in",
    403: "Forbidden",
    404: "Not found",
    405: "Method not allowed",
    409: "Conflict",
    410: "Gone",
    411: "Length required",
    413: "Content too large",
    415: "Unsupported media type",
    416: "Range not satisfiable",
    422: "Invalid input",
    429: "Too many requests",
    500: "Internal error",
    503: "Not ready",
}


class ValidationIssue(TypedDict):
    """One part of a request that failed validation, as FastAPI (pydantic) reported it."""

    loc: Annotated[
        list[str | int],
        Field(
            description="Where: `body`, `query`, `path` or `header`, then field names and "
            'list indexes, e.g. `["body", "steps", 0, "name"]`.'
        ),
    ]
    msg: Annotated[str, Field(description="What is wrong, in pydantic's words.")]
    type: Annotated[str, Field(description="pydantic's error type, e.g. `missing`.")]


class ProblemDetails(TypedDict):
    """Every error the API answers (RFC 9457, `application/problem+json`). `detail` is the
    sentence to show a person. A 422 refused by validation also lists each refused part
    in `errors`; a 422 from a rule checked later (a reference to something that does not
    exist, a combination of fields, the content of an upload) has `detail` only."""

    type: Annotated[
        str, Field(description="Always `about:blank`: the status says what kind of problem.")
    ]
    title: Annotated[
        str, Field(description="The status in words, e.g. `Not found`, `Invalid input`.")
    ]
    status: Annotated[int, Field(ge=400, le=599, description="The HTTP status code again.")]
    detail: Annotated[str, Field(description="What went wrong and what to do about it.")]
    instance: NotRequired[Annotated[str, Field(description="The path of the request.")]]
    errors: NotRequired[
        Annotated[
            list[ValidationIssue],
            Field(description="Only on a 422 from request validation: every refused part."),
        ]
    ]


class Problem(Exception):
    """Raise anywhere below a router to answer with a problem document."""

    def __init__(
        self, status: int, detail: str, *, headers: dict[str, str] | None = None, **extra: Any
    ) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.headers = headers
        self.extra = extra


def not_found(what: str, ident: object) -> Problem:
    return Problem(404, f"There is no {what} with id {ident}.")


def problem_response(
    status: int, detail: str, *, instance: str = "", headers: dict[str, str] | None = None, **extra
) -> JSONResponse:
    body = {"type": "about:blank", "title": _TITLES.get(status, "Error"), "status": status}
    body["detail"] = detail
    if instance:
        body["instance"] = instance
    body.update(extra)
    return JSONResponse(body, status_code=status, headers=headers, media_type=PROBLEM_MEDIA_TYPE)


def _location(loc: tuple | list) -> str:
    parts = [str(p) for p in loc if p not in ("body",)]
    text = ""
    for part in parts:
        text += f"[{part}]" if part.isdigit() else (f".{part}" if text else part)
    return text or "the request body"


def _validation_sentence(errors: list[dict]) -> str:
    sentences = []
    for error in errors[:5]:
        where = _location(error.get("loc", ()))
        message = error.get("msg", "is invalid")
        if error.get("type") == "extra_forbidden":
            message = "is not a known field"
        elif error.get("type") == "missing":
            message = "is required"
        sentences.append(f"{where}: {message}")
    more = f" (and {len(errors) - 5} more)" if len(errors) > 5 else ""
    return "; ".join(sentences) + more + "."


def install_problem_handlers(app: FastAPI) -> None:
    @app.exception_handler(Problem)
    async def _problem(request: Request, exc: Problem) -> JSONResponse:
        return problem_response(
            exc.status, exc.detail, instance=request.url.path, headers=exc.headers, **exc.extra
        )

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            {"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in exc.errors()
        ]
        return problem_response(
            422, _validation_sentence(errors), instance=request.url.path, errors=errors
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"There is nothing at {request.url.path}."
        elif exc.status_code == 405:
            detail = f"{request.method} is not allowed on {request.url.path}."
        return problem_response(
            exc.status_code, detail, instance=request.url.path, headers=exc.headers
        )

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem_response(
            500,
            f"The server failed on this request ({type(exc).__name__}); it has been logged.",
            instance=request.url.path,
        )
