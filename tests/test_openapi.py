"""The OpenAPI document tells the truth about errors: every error is a problem document of
the one declared schema, and the statuses each operation can answer are listed — checked
on the document and against what the API answers people whose role refuses them."""

from __future__ import annotations

import httpx
import pytest
from jsonschema import Draft202012Validator
from referencing import Registry
from referencing.jsonschema import DRAFT202012

from supervisor.app import create_app
from supervisor.deps import DEVICE_WRITE_PATHS
from supervisor.openapi import ERRORS, FILE_DOWNLOADS, IDEMPOTENT, PROBLEM_SCHEMA
from supervisor.problems import PROBLEM_MEDIA_TYPE
from tests.conftest import auth, make_settings
from tests.plyfiles import ply_bytes
from tests.seeding import seed_defects

PUBLIC = {"POST /api/v1/auth/token", "GET /api/v1/healthz", "GET /api/v1/readyz"}
PROBLEM_REF = {"$ref": f"#/components/schemas/{PROBLEM_SCHEMA}"}
RANGE_ERRORS = {"400", "416"}
"""Answered in plain text by the file server for a bad ``Range`` (see FILE_DOWNLOADS)."""


@pytest.fixture(scope="module")
def document(tmp_path_factory: pytest.TempPathFactory) -> dict:
    tmp_path = tmp_path_factory.mktemp("openapi")
    return create_app(make_settings(tmp_path, f"sqlite:///{tmp_path}/unused.db")).openapi()


def operations(document: dict) -> dict[str, dict]:
    return {
        f"{method.upper()} {path}": operation
        for path, methods in document["paths"].items()
        for method, operation in methods.items()
    }


def problem_validator(document: dict) -> Draft202012Validator:
    registry = Registry().with_resource("urn:openapi", DRAFT202012.create_resource(document))
    schema = {"$ref": f"urn:openapi#/components/schemas/{PROBLEM_SCHEMA}"}
    return Draft202012Validator(schema, registry=registry)


def test_every_error_is_a_problem_document_of_the_one_schema(document):
    checked = 0
    for name, operation in operations(document).items():
        for status, response in operation["responses"].items():
            if int(status) < 400:
                continue
            content = response["content"]
            if name in FILE_DOWNLOADS and status in RANGE_ERRORS:
                assert "text/plain" in content, (name, status)
                content = {k: v for k, v in content.items() if k != "text/plain"}
                if not content:
                    continue
            assert content == {PROBLEM_MEDIA_TYPE: {"schema": PROBLEM_REF}}, (name, status)
            assert response["description"].strip(), (name, status)
            checked += 1
    assert checked > 150
    schemas = document["components"]["schemas"]
    assert "HTTPValidationError" not in schemas and "ValidationError" not in schemas
    problem = schemas[PROBLEM_SCHEMA]
    assert problem["required"] == ["type", "title", "status", "detail"]
    assert set(problem["properties"]) == {"type", "title", "status", "detail", "instance", "errors"}


def test_the_generic_statuses_are_listed_where_due(document):
    for name, operation in operations(document).items():
        method, path = name.split(" ", 1)
        responses = operation["responses"]
        if name in PUBLIC:
            assert "security" not in operation, name
        else:
            assert operation["security"] == [{"HTTPBearer": []}], name
            assert responses["401"]["headers"]["WWW-Authenticate"]["required"], name
            if method != "GET" and path not in DEVICE_WRITE_PATHS:
                assert "403" in responses, name  # a device token may not write
        parameters = operation.get("parameters", [])
        if any(p["in"] == "path" for p in parameters):
            assert "404" in responses, name
        if parameters or "requestBody" in operation:
            assert "422" in responses, name
        else:
            assert "422" not in responses, name
        if list(operation.get("requestBody", {}).get("content", {})) == ["application/json"]:
            assert "400" in responses, name  # a body that is not UTF-8
    assert (
        "Retry-After"
        in operations(document)["POST /api/v1/auth/token"]["responses"]["429"]["headers"]
    )


def test_the_per_operation_lists_name_real_operations(document):
    named = operations(document)
    assert set(ERRORS) <= set(named)
    assert set(IDEMPOTENT) <= set(named) and set(FILE_DOWNLOADS) <= set(named)
    for name in IDEMPOTENT:
        parameters = {p["name"] for p in named[name]["parameters"] if p["in"] == "header"}
        assert "Idempotency-Key" in parameters, name
        assert named[name]["responses"]["201"]["headers"]["Location"]["required"], name
    for name, statuses in ERRORS.items():
        assert {str(s) for s in statuses} <= set(named[name]["responses"]), name


def _request(name: str, operation: dict) -> dict:
    """A request for ``name`` with ids 1 and the least input its schema needs."""
    method, path = name.split(" ", 1)
    query = {}
    for parameter in operation.get("parameters", []):
        schema = parameter["schema"]
        value = 1 if schema.get("type") == "integer" else schema.get("enum", ["x"])[0]
        if parameter["in"] == "path":
            path = path.replace(f"{{{parameter['name']}}}", str(value))
        elif parameter["in"] == "query" and parameter.get("required"):
            query[parameter["name"]] = value
    request = {"method": method, "url": path, "params": query}
    body = operation.get("requestBody", {}).get("content", {})
    if "application/json" in body and len(body) == 1:
        request["json"] = {}
    elif body:
        request["content"] = b"x"
        request["headers"] = {"Content-Type": "application/octet-stream"}
    return request


@pytest.mark.parametrize("role", ["viewer", "device"])
def test_people_refused_get_the_statuses_the_document_lists(client, tokens, role):
    """Every operation, asked by a viewer and by a headset (the fuzz test signs in as an
    admin): what they get is documented, and every error is a valid problem document."""
    document = client.get("/api/v1/openapi.json").json()
    validator = problem_validator(document)
    named = operations(document)
    # Signing out ends the token: last.
    for name in sorted(named, key=lambda n: n == "DELETE /api/v1/auth/token"):
        request = _request(name, named[name])
        request.setdefault("headers", {}).update(auth(tokens[role]))
        response = client.request(**request)
        assert str(response.status_code) in named[name]["responses"], (name, response.text)
        if response.status_code >= 400:
            assert response.headers["content-type"] == PROBLEM_MEDIA_TYPE, name
            validator.validate(response.json())


def test_answers_built_by_hand_are_the_declared_ones(client, tokens, runtime, tmp_path):
    """Sign-in, sync (gzip'd when large), a judgment and a file download build their
    answers by hand, past FastAPI's response models: each matches the document."""
    document = client.get("/api/v1/openapi.json").json()
    registry = Registry().with_resource("urn:openapi", DRAFT202012.create_resource(document))
    named = operations(document)

    def check(name: str, response: httpx.Response) -> None:
        declared = named[name]["responses"][str(response.status_code)]
        media_type = response.headers["content-type"].split(";")[0]
        assert media_type in declared["content"], (name, media_type)
        for header, spec in declared.get("headers", {}).items():
            assert not spec["required"] or header in response.headers, (name, header)
        schema = declared["content"][media_type].get("schema", {})
        if "$ref" in schema:
            ref = {"$ref": f"urn:openapi{schema['$ref']}"}
            Draft202012Validator(ref, registry=registry).validate(response.json())

    admin = auth(tokens["admin"])
    signed_in = client.post(
        "/api/v1/auth/token", json={"username": "ada", "password": "admin-password"}
    )
    check("POST /api/v1/auth/token", signed_in)
    inspection = client.post(
        "/api/v1/inspections", json={"title": "t", "area": "cabin"}, headers=admin
    ).json()["id"]
    defect = seed_defects(runtime, inspection, 40)[0]
    synced = client.get(
        "/api/v1/sync",
        params={"inspection": inspection},
        headers=admin | {"Accept-Encoding": "gzip"},
    )
    assert synced.headers["content-encoding"] == "gzip"
    check("GET /api/v1/sync", synced)
    judged = client.put(
        f"/api/v1/defects/{defect}/judgments/me", json={"verdict": "confirmed"}, headers=admin
    )
    check("PUT /api/v1/defects/{defect_id}/judgments/me", judged)
    item = {
        "client_id": "c-1",
        "defect_id": defect,
        "verdict": "rejected",
        "client_time": "2026-01-01T00:00:00Z",
    }
    pushed = client.post("/api/v1/sync/judgments", json={"items": [item]}, headers=admin)
    check("POST /api/v1/sync/judgments", pushed)
    scan = client.post(
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": "scan", "name": "s.ply"},
        content=ply_bytes(tmp_path),
        headers=admin | {"Content-Type": "application/x-ply"},
    )
    check("POST /api/v1/inspections/{inspection_id}/artifacts", scan)
    content = f"/api/v1/inspections/{inspection}/artifacts/{scan.json()['id']}/content"
    name = "GET /api/v1/inspections/{inspection_id}/artifacts/{artifact_id}/content"
    for extra, status in (
        ({}, 200),
        ({"Range": "bytes=0-9"}, 206),
        ({"Range": "bytes=9999999-"}, 416),
    ):
        response = client.get(content, headers=admin | extra)
        assert response.status_code == status
        check(name, response)
