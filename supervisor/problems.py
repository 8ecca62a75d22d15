"""Errors as RFC 9457 problem details, each with a sentence a person can act on."""

from __future__ import annotations

import logging
from typing import Annotated, Any, NotRequired

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import iter_route_contexts
from pydantic import Field
from sqlalchemy.exc import DBAPIError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match
from typing_extensions import TypedDict  # pydantic reads typing.TypedDict from 3.12 only

from supervisor.engine.transient import is_transient

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


def _listed(values: object) -> str:
    """ "'a', 'b' or 'c'" from pydantic's ``expected`` ("'a', 'b' or 'c'") or a list."""
    if isinstance(values, list | tuple):
        quoted = [repr(v) for v in values]
        return ", ".join(quoted[:-1]) + f" or {quoted[-1]}" if len(quoted) > 1 else "".join(quoted)
    return str(values)


_PHRASES: dict[str, str] = {
    "missing": "is required",
    "extra_forbidden": "is not a known field",
    "model_type": "must be an object of named fields ({{…}})",
    "model_attributes_type": "must be an object of named fields ({{…}})",
    "dict_type": "must be an object of named fields ({{…}})",
    "list_type": "must be a list ([…])",
    "tuple_type": "must be a list ([…])",
    "string_type": "must be text",
    "int_type": "must be a whole number",
    "int_parsing": "must be a whole number",
    "int_from_float": "must be a whole number",
    "float_type": "must be a number",
    "float_parsing": "must be a number",
    "finite_number": "must be a finite number",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
    "greater_than": "must be greater than {gt}",
    "greater_than_equal": "must be at least {ge}",
    "less_than": "must be less than {lt}",
    "less_than_equal": "must be at most {le}",
    "string_too_short": "must have at least {min_length} character(s)",
    "string_too_long": "must have at most {max_length} characters",
    "too_short": "must have at least {min_length} item(s)",
    "too_long": "must have at most {max_length} items",
    "string_pattern_mismatch": "does not have the form allowed ({pattern})",
    "literal_error": "must be one of {expected}",
    "enum": "must be one of {expected}",
    "datetime_type": "must be a date and time (ISO 8601, e.g. 2026-11-27T10:00:00Z)",
    "datetime_parsing": "must be a date and time (ISO 8601, e.g. 2026-11-27T10:00:00Z)",
    "datetime_from_date_parsing": "must be a date and time (ISO 8601, e.g. 2026-11-27T10:00:00Z)",
}
"""pydantic's error types in words: what is allowed (its context fills the braces)."""


def issue_sentence(error: dict, prefix: tuple = ()) -> str:
    """One refused part (a pydantic error, its ``loc`` under ``prefix``) as "where: what is
    allowed"."""
    error = {**error, "loc": (*prefix, *error.get("loc", ()))}
    kind, context = error.get("type", ""), error.get("ctx") or {}
    if kind == "json_invalid":
        at = next((p for p in reversed(error.get("loc", ())) if isinstance(p, int)), None)
        where = f" at character {at}" if at is not None else ""
        return f"The request body is not valid JSON ({context.get('error', 'it does not parse')}{where})"
    where = _location(error.get("loc", ()))
    if kind in _PHRASES:
        try:
            return f"{where}: {_PHRASES[kind].format(**{k: _listed(v) if k == 'expected' else v for k, v in context.items()})}"
        except (KeyError, IndexError):
            pass
    message = str(error.get("msg", "is not allowed"))
    message = message.removeprefix("Value error, ").removeprefix("Assertion failed, ")
    message = message.replace("Input should be", "must be")
    return f"{where}: {message}"


def _validation_sentence(errors: list[dict]) -> str:
    sentences = [issue_sentence(error) for error in errors[:5]]
    more = f" (and {len(errors) - 5} more)" if len(errors) > 5 else ""
    return "; ".join(sentences) + more + "."


def _allowed_methods(request: Request) -> list[str]:
    """Every method some route of this path answers (Starlette's ``Allow`` lists those of
    the first route it matched only: a path served by a GET route and a PUT route said
    ``Allow: GET``)."""
    scope = {**request.scope, "method": "GET"}
    methods: set[str] = set()
    for route in iter_route_contexts(request.app.router.routes):  # included routers' too
        match, _ = route.matches(scope)
        if match is not Match.NONE:
            methods |= route.methods or set()
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


OUTAGE_RETRY_AFTER_S = 2
"""A database that went away is back within seconds (a restart) or not soon at all."""


def install_problem_handlers(app: FastAPI) -> None:
    @app.exception_handler(Problem)
    async def _problem(request: Request, exc: Problem) -> JSONResponse:
        return problem_response(
            exc.status, exc.detail, instance=request.url.path, headers=exc.headers, **exc.extra
        )

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        raw = exc.errors()
        errors = [
            {"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in raw
        ]
        return problem_response(
            422, _validation_sentence(list(raw)), instance=request.url.path, errors=errors
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"There is nothing at {request.url.path}."
        headers = exc.headers
        if exc.status_code == 405:
            allowed = _allowed_methods(request)
            detail = (
                f"{request.method} is not allowed on {request.url.path}: {', '.join(allowed)} are."
            )
            headers = {**(headers or {}), "Allow": ", ".join(allowed)}
        return problem_response(exc.status_code, detail, instance=request.url.path, headers=headers)

    async def _fault(request: Request, exc: Exception) -> JSONResponse:
        """The database (or the network to it) away: 503. Handled here, by class, and not
        by the handler of every ``Exception`` below, which Starlette runs after the fact
        and then raises again — the server closes the connection, and a client on it
        reads a reset."""
        if not is_transient(exc):
            return await _unexpected(request, exc)
        log.warning("%s %s: a passing fault: %s", request.method, request.url.path, exc)
        return problem_response(
            503,
            f"The database cannot be reached just now; try again in {OUTAGE_RETRY_AFTER_S} s.",
            instance=request.url.path,
            headers={"Retry-After": str(OUTAGE_RETRY_AFTER_S)},
        )

    for fault in (DBAPIError, ConnectionError, TimeoutError):
        app.add_exception_handler(fault, _fault)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem_response(
            500,
            f"The server failed on this request ({type(exc).__name__}); it has been logged.",
            instance=request.url.path,
        )
