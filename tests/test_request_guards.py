"""Everything deep or odd is a 4xx: every route that reads a JSON body refuses one nested
too deep or too large before it is parsed, digested or validated; a method a path does not
answer is a 405 whose ``Allow`` lists every method it does."""

from __future__ import annotations

import re

import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute, iter_route_contexts

from supervisor.requests import MAX_JSON_BODY_BYTES, MAX_JSON_BODY_DEPTH
from tests.conftest import auth


def _api_routes(app: FastAPI) -> list:
    """Every API route as served (an included router's with its prefix)."""
    return [r for r in iter_route_contexts(app.routes) if isinstance(r.original_route, APIRoute)]


def _json_routes(app: FastAPI) -> list[tuple[str, str]]:
    return sorted(
        (method, route.path)
        for route in _api_routes(app)
        if route.original_route.body_field is not None
        for method in route.methods
    )


def _filled(path: str) -> str:
    return re.sub(r"\{[^}]+\}", "1", path)


def _nested(depth: int) -> bytes:
    """``{"a": {"a": … []}}``: ``depth`` levels, as a body any of the API's models reads."""
    return b'{"a":' * (depth - 1) + b"[]" + b"}" * (depth - 1)


@pytest.mark.parametrize("depth", [MAX_JSON_BODY_DEPTH + 1, 256, 100_000])
def test_every_json_body_too_deep_is_a_422_before_anything_reads_it(client, tokens, depth):
    routes = _json_routes(client.app)
    assert len(routes) >= 10, routes
    headers = {**auth(tokens["admin"]), "Content-Type": "application/json"}
    for method, path in routes:
        answer = client.request(method, _filled(path), content=_nested(depth), headers=headers)
        assert answer.status_code == 422, (method, path, answer.status_code, answer.text[:200])
        assert "levels deep" in answer.json()["detail"], (method, path, answer.text[:200])


def test_run_params_at_any_depth_are_a_4xx(client, tokens):
    """The issue's case: a run's params 256 levels deep got a 500 from the idempotency
    digest's serialiser (255 levels were a 422)."""
    headers = auth(tokens["inspector"])
    inspection = client.post(
        "/api/v1/inspections", json={"title": "deep", "area": "cabin"}, headers=headers
    ).json()["id"]
    for depth in (5, 31, 255, 256, 300):
        params = "[]"
        for _ in range(depth - 4):  # body, steps, step, params: four levels around it
            params = '{"a":' + params + "}"
        body = f'{{"steps":[{{"name":"s","kind":"test.sleep","params":{params},"after":[]}}]}}'
        answer = client.post(
            f"/api/v1/inspections/{inspection}/runs",
            content=body.encode(),
            headers={**headers, "Content-Type": "application/json"},
        )
        assert 400 <= answer.status_code < 500, (depth, answer.status_code, answer.text[:200])


def test_a_json_body_too_large_is_a_413(client, tokens):
    headers = {**auth(tokens["inspector"]), "Content-Type": "application/json"}
    body = b'{"title": "' + b"x" * (MAX_JSON_BODY_BYTES + 1) + b'", "area": "cabin"}'
    answer = client.post("/api/v1/inspections", content=body, headers=headers)
    assert answer.status_code == 413, answer.text[:200]


def test_a_405_lists_every_method_its_path_answers(client, tokens):
    """Each path the API serves, asked with a method none of its routes answers: 405, and
    ``Allow`` the union of the methods of every route whose pattern takes that path
    (Starlette listed the first route's: 17 of schemathesis' 19 failures)."""
    routes = _api_routes(client.app)
    for path in sorted({route.path for route in routes}):
        concrete = _filled(path)
        methods = set().union(*(r.methods for r in routes if r.path_regex.match(concrete)))
        unused = next(m for m in ("PATCH", "PUT", "DELETE", "POST") if m not in methods)
        answer = client.request(unused, concrete, headers=auth(tokens["admin"]))
        assert answer.status_code == 405, (unused, path, answer.status_code)
        allowed = {m.strip() for m in answer.headers["allow"].split(",")}
        assert allowed == methods | ({"HEAD"} if "GET" in methods else set()), (path, allowed)
