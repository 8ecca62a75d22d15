"""The OpenAPI document made true to what the API answers.

FastAPI documents each operation's success and a 422 of its own shape; the API answers
every error as a problem document (``supervisor.problems``). ``document_errors`` rewrites
the generated document once: every error response is ``application/problem+json`` with
the one ``ProblemDetails`` schema, each operation lists the statuses it can answer (the
generic ones derived from the operation itself, the rest from ``ERRORS``, read off the
code), and the headers the code reads or sends by hand are declared.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import FastAPI
from pydantic import TypeAdapter

from supervisor.deps import DEVICE_WRITE_PATHS
from supervisor.idempotency import KEY_HEADER, MAX_KEY_LENGTH
from supervisor.problems import PROBLEM_MEDIA_TYPE, ProblemDetails

PROBLEM_SCHEMA = "ProblemDetails"
REF_TEMPLATE = "#/components/schemas/{model}"

CURSOR = (
    "The `next_cursor` of the page before (none: the first page). Opaque: only cursors "
    "this server gave out are read (400 otherwise)."
)
EDITORS = "Only admins and inspectors may do this."
ADMINS = "Only admins may do this."
JUDGES = "Viewers may not judge defects."

ERRORS: dict[str, dict[int, str]] = {
    "POST /api/v1/auth/token": {
        401: "Unknown username or wrong password.",
        429: "Too many sign-ins from this address, too many failed ones for this username "
        "(each per minute), or too many at once: try again after `Retry-After` seconds.",
    },
    "PUT /api/v1/me/password": {403: "`current_password` is not your current password."},
    "POST /api/v1/users": {403: ADMINS, 409: "A user of that name exists."},
    "GET /api/v1/users": {403: ADMINS},
    "GET /api/v1/users/{user_id}": {403: ADMINS},
    "PATCH /api/v1/users/{user_id}": {
        403: ADMINS,
        409: "The last active admin cannot be deactivated or given another role.",
        422: "`password` given for a device account (devices sign in with tokens only).",
    },
    "POST /api/v1/users/{user_id}/tokens": {
        403: ADMINS,
        409: "The user is deactivated: reactivate them first.",
    },
    "GET /api/v1/tokens": {403: "`user` is someone else, and you are not an admin."},
    "DELETE /api/v1/tokens/{token_id}": {
        404: "For a non-admin, another user's token is not found either."
    },
    "POST /api/v1/tokens/revoke": {
        403: "`device`, or a `user_id` other than yours, and you are not an admin.",
        404: "`user_id` names no user.",
    },
    "POST /api/v1/inspections": {403: EDITORS},
    "PATCH /api/v1/inspections/{inspection_id}": {
        403: f"{EDITORS} Changing `tolerances`, or closing or reopening the inspection, is for "
        "its owner (`created_by`) or an admin.",
        422: "A rule the schema cannot state: see the description.",
    },
    "POST /api/v1/defects/{defect_id}/notes": {403: EDITORS},
    "POST /api/v1/tolerance-sets": {
        403: EDITORS,
        409: "A tolerance set of that name exists.",
        422: "A rule the schema cannot state: a gap range's min below its max.",
    },
    "PATCH /api/v1/tolerance-sets/{set_id}": {
        403: f"{EDITORS} Only the set's maker or an admin may change it.",
        409: "Another tolerance set has that name.",
        422: "A rule the schema cannot state: the merged gap range's min below its max.",
    },
    "DELETE /api/v1/tolerance-sets/{set_id}": {
        403: f"{EDITORS} Only the set's maker or an admin may delete it."
    },
    "POST /api/v1/inspections/{inspection_id}/tolerance-set": {
        403: f"{EDITORS} Only the inspection's owner or an admin may change its tolerances.",
    },
    "DELETE /api/v1/inspections/{inspection_id}": {
        403: f"{EDITORS} Only the inspection's owner or an admin may delete it.",
        409: "The inspection has queued or running jobs: cancel them first.",
    },
    "GET /api/v1/trash/inspections": {403: ADMINS},
    "POST /api/v1/trash/inspections/{inspection_id}/restore": {403: ADMINS},
    "DELETE /api/v1/trash/inspections/{inspection_id}": {403: ADMINS},
    "POST /api/v1/inspections/{inspection_id}/artifacts": {
        400: "`Content-Length` is not a whole number.",
        403: EDITORS,
        413: "The file is larger than the server's upload limit (VISTA_MAX_UPLOAD_BYTES), "
        "or a JSON or TUM file is larger than 256 MiB.",
        415: "The Content-Type is not one of the media types of the request body.",
        422: "The file is empty, or its content is not what `kind` needs: see the description.",
    },
    "DELETE /api/v1/inspections/{inspection_id}/artifacts/{artifact_id}": {
        403: f"{EDITORS} Only who uploaded the artifact, the inspection's owner or an admin "
        "may delete it.",
        409: "The artifact is an input of an unfinished job.",
    },
    "GET /api/v1/inspections/{inspection_id}/artifacts/{artifact_id}/content": {
        410: "The artifact's file is missing from storage."
    },
    "POST /api/v1/inspections/{inspection_id}/runs": {
        403: EDITORS,
        422: "A step breaks a rule the schema cannot state: see the description.",
    },
    "POST /api/v1/jobs/{job_id}/cancel": {403: EDITORS, 409: "The job has finished already."},
    "GET /api/v1/jobs/{job_id}/scene.glb": {
        409: "The job has not succeeded (no scene yet), or its results could not be drawn."
    },
    "POST /api/v1/jobs/{job_id}/retry": {
        403: EDITORS,
        409: "The job is neither failed nor cancelled.",
    },
    "POST /api/v1/defects": {
        403: EDITORS,
        422: "`inspection_id` names no inspection (or one in the trash), or `normal` is the "
        "zero vector.",
    },
    "PATCH /api/v1/defects/{defect_id}": {
        403: f"{EDITORS} Dismissing a critical defect is for its inspection's owner or an admin.",
        422: "Dismissing without a `reason`.",
    },
    "PUT /api/v1/defects/{defect_id}/judgments/me": {
        403: JUDGES,
        422: "`reclassified` as the defect's own type.",
    },
    "GET /api/v1/sync": {
        400: "`since` is not a cursor this server gave out for this inspection: sync from "
        "the start (`since=0`).",
        404: "`inspection` names no inspection.",
        410: "The inspection was deleted since the cursor `since` was given: drop the local copy.",
    },
    "POST /api/v1/sync/judgments": {403: JUDGES},
    "GET /api/v1/feedback": {404: "`inspection` names no inspection."},
    "GET /api/v1/audit": {
        403: "No `inspection` given, and you are not an admin.",
        404: "`inspection` names no inspection (checked for non-admins).",
    },
    "GET /api/v1/readyz": {503: "The database, or the broker when there is one, does not answer."},
}
"""Per operation, the statuses it answers beyond the generic ones (see ``_generic``)."""

IDEMPOTENT = (
    "POST /api/v1/users",
    "POST /api/v1/inspections",
    "POST /api/v1/inspections/{inspection_id}/artifacts",
    "POST /api/v1/inspections/{inspection_id}/runs",
    "POST /api/v1/defects",
    "POST /api/v1/tolerance-sets",
)
"""The creating POSTs that honour ``Idempotency-Key`` (``supervisor.idempotency``)."""

FILE_DOWNLOADS = (
    "GET /api/v1/inspections/{inspection_id}/artifacts/{artifact_id}/content",
    "GET /api/v1/inspections/{inspection_id}/scene.glb",
)
"""Operations answering with a file, which serves byte ranges (``Range``) itself."""

_IDEMPOTENCY_KEY = {
    "name": KEY_HEADER,
    "in": "header",
    "required": False,
    "description": "Any new key (e.g. a UUID) per request: a retry with the same key and "
    "body gets the first response again (with `Idempotent-Replayed: true`) and creates "
    "nothing; the same key with another body is refused (422).",
    "schema": {"type": "string", "minLength": 1, "maxLength": MAX_KEY_LENGTH},
}
_IF_NONE_MATCH = {
    "name": "If-None-Match",
    "in": "header",
    "required": False,
    "description": "The ETag of the copy you have (or `*`): 304 while it is current.",
    "schema": {"type": "string"},
}
_HEADERS = {
    "WWW-Authenticate": {
        "description": "`Bearer`.",
        "required": True,
        "schema": {"type": "string"},
    },
    "Retry-After": {
        "description": "Seconds to wait before trying again.",
        "required": True,
        "schema": {"type": "integer", "minimum": 1},
    },
    "Location": {
        "description": "The path of what was created.",
        "required": True,
        "schema": {"type": "string"},
    },
    "ETag": {
        "description": "The version of the file.",
        "required": True,
        "schema": {"type": "string"},
    },
}
_PLAIN_TEXT = {"text/plain": {"schema": {"type": "string"}}}


def install_openapi(app: FastAPI) -> None:
    """Serve ``app``'s generated document with ``document_errors`` applied."""
    generate: Callable[[], dict[str, Any]] = app.openapi

    def openapi() -> dict[str, Any]:
        document = generate()  # cached by FastAPI until the routes change
        if PROBLEM_SCHEMA not in document.get("components", {}).get("schemas", {}):
            document_errors(document)
        return document

    app.openapi = openapi


def document_errors(document: dict[str, Any]) -> dict[str, Any]:
    """Rewrite ``document`` (in place, and return it) as the module docstring says."""
    schemas = document.setdefault("components", {}).setdefault("schemas", {})
    problem = TypeAdapter(ProblemDetails).json_schema(ref_template=REF_TEMPLATE)
    schemas.update(problem.pop("$defs", {}))
    schemas[PROBLEM_SCHEMA] = problem
    for path, operations in document["paths"].items():
        for method, operation in operations.items():
            name = f"{method.upper()} {path}"
            reasons = _generic(path, method, operation)
            for status, reason in ERRORS.get(name, {}).items():
                reasons.setdefault(status, []).append(reason)
            for parameter in operation.get("parameters", []):
                if parameter["in"] == "query" and parameter["name"] == "cursor":
                    parameter["description"] = CURSOR
            responses = operation["responses"]
            for status, said in sorted(reasons.items()):
                responses[str(status)] = _problem(
                    status, " ".join(said), secured=bool(operation.get("security"))
                )
            if name in IDEMPOTENT:
                operation.setdefault("parameters", []).append(_IDEMPOTENCY_KEY)
                responses["201"]["headers"] = {"Location": _HEADERS["Location"]}
            if name in FILE_DOWNLOADS:
                _document_ranges(responses)
            if name == "GET /api/v1/inspections/{inspection_id}/scene.glb":
                operation["parameters"].append(_IF_NONE_MATCH)
                responses["304"]["headers"] = {"ETag": _HEADERS["ETag"]}
    for unused in ("HTTPValidationError", "ValidationError"):
        schemas.pop(unused, None)
    return document


def _generic(path: str, method: str, operation: dict[str, Any]) -> dict[int, list[str]]:
    """The statuses an operation answers by its shape: 401 and a device token's 403 when it
    needs a bearer token, 404 for ids in its path, 422 (and 400 for a body that cannot
    be read, or a foreign `cursor`) when it takes input."""
    reasons: dict[int, list[str]] = {}
    if operation.get("security"):
        reasons[401] = [
            "No bearer token, or one that is unknown, expired or revoked, or whose user is "
            "deactivated: sign in again."
        ]
        if method != "get" and path not in DEVICE_WRITE_PATHS:
            reasons[403] = ["A device token may only read and sync: sign in as a person."]
    parameters = operation.get("parameters", [])
    ids = [p["name"].removesuffix("_id") for p in parameters if p["in"] == "path"]
    if ids:
        said = f"There is no {' or '.join(ids)} with that id"
        if path.startswith("/api/v1/trash/"):
            said = f"There is no {' or '.join(ids)} in the trash with that id"
        elif not path.startswith(("/api/v1/users/", "/api/v1/tokens/")):
            said += " (an inspection in the trash, and what it holds, is not found either)"
        reasons[404] = [f"{said}."]
    body = operation.get("requestBody", {}).get("content", {})
    if parameters or body:
        reasons[422] = [
            "Part of the request does not match the schema: `detail` names it, `errors` "
            "lists every such part."
        ]
    if list(body) == ["application/json"]:
        reasons.setdefault(400, []).append("The JSON body is not UTF-8 text.")
    if any(p["name"] == "cursor" and p["in"] == "query" for p in parameters):
        reasons.setdefault(400, []).append(
            "`cursor` is not one this server gave out: start without it."
        )
    if f"{method.upper()} {path}" in IDEMPOTENT:
        reasons.setdefault(400, []).append(
            f"`{KEY_HEADER}` is empty or longer than {MAX_KEY_LENGTH} characters."
        )
        reasons[422].append(f"The `{KEY_HEADER}` was used before for another request.")
    return reasons


def _problem(status: int, description: str, *, secured: bool) -> dict[str, Any]:
    response: dict[str, Any] = {
        "description": description,
        "content": {
            PROBLEM_MEDIA_TYPE: {"schema": {"$ref": REF_TEMPLATE.format(model=PROBLEM_SCHEMA)}}
        },
    }
    if status == 401 and secured:
        response["headers"] = {"WWW-Authenticate": _HEADERS["WWW-Authenticate"]}
    if status == 429:
        response["headers"] = {"Retry-After": _HEADERS["Retry-After"]}
    return response


def _document_ranges(responses: dict[str, Any]) -> None:
    """A file response also answers ``Range`` requests: 206 with the bytes asked for,
    and — from the file server, in plain text, not as problems — 400 for a malformed
    range and 416 for one beyond the file."""
    whole = responses["200"]
    whole.setdefault("headers", {})["ETag"] = _HEADERS["ETag"]
    content = dict(whole.get("content", {}))
    content["multipart/byteranges"] = {"schema": {"type": "string", "format": "binary"}}
    responses["206"] = {
        "description": "The byte ranges asked for in `Range` (one range: its bytes, with "
        "`Content-Range`; several: `multipart/byteranges`).",
        "content": content,
    }
    bad_range = "A malformed `Range` header (from the file server, in plain text)."
    if "400" in responses:
        responses["400"]["description"] += f" {bad_range}"
        responses["400"]["content"].update(_PLAIN_TEXT)
    else:
        responses["400"] = {"description": bad_range, "content": dict(_PLAIN_TEXT)}
    responses["416"] = {
        "description": "`Range` starts beyond the end of the file (in plain text, with "
        "`Content-Range: bytes */<size>`).",
        "content": dict(_PLAIN_TEXT),
    }
