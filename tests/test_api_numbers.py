"""Numbers are checked at the door: every number field of every JSON request body the
OpenAPI schema declares, set to a non-finite or extreme value, is answered with a 422 that
names the field — never a 5xx, and with nothing stored."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from sqlalchemy import func, select

from supervisor.db import Base
from supervisor.demo import TOLERANCES as DEMO_TOLERANCES
from tests.conftest import auth
from tests.depthfiles import pack_drive, small_drive, tiny_depth_model
from tests.lidarfiles import pack_sequence
from tests.lidarfiles import small_drive as small_lidar_drive
from tests.plyfiles import ply_bytes
from tests.sequences import pack, small_sequence

BAD_NUMBERS = (
    "NaN",
    "Infinity",
    "-Infinity",
    "1e400",  # beyond a double: JSON parsers read it as infinity
    "-1e400",
    "1e308",
    "-1e308",
    "9223372036854775808",  # 2⁶³: beyond a 64-bit integer column
    "-1e30",
)
PYDANTIC = re.compile(r"Input should|Value error|JSON decode error|dictionary or object")
"""pydantic's own words: a 4xx detail is a sentence for a person instead."""
NOT_JSON = {("POST", "/api/v1/inspections/{inspection_id}/artifacts")}
"""Bodies that are files, not JSON documents (their checks are in test_api_artifacts)."""
REQUIRED_PARAMS = {
    "tracking.track": ({"track_id": 0}, {"init_box": [1.5, 1.6, 3.9, 0.0, 1.7, 10.0, 0.0]}),
}
"""The params a job kind cannot run without (all others have defaults), in each of the
ways it takes them: each way's numbers are checked on a body holding it."""
MARKER = [[1.0, 0.0, 0.0, 10.0], [0.0, 1.0, 0.0, 20.0], [0.0, 0.0, 1.0, 30.0], [0, 0, 0, 1.0]]


TOLERANCES = {**DEMO_TOLERANCES, "profile_mm": {"min": -0.3, "max": 0.4}}
"""Every limit, the profile band's too."""


def _bodies(ids: dict[str, int]) -> dict[tuple[str, str], dict]:
    """A valid body for every JSON operation, holding every number field its schema has."""
    marker = {"name": "m1", "area": "cabin", "base_T_marker": MARKER, "size_mm": 100.0}
    inspection = {"title": "t", "area": "cabin", "tolerances": TOLERANCES, "markers": [marker]}
    return {
        ("POST", "/api/v1/auth/token"): {"username": "ada", "password": "admin-password"},
        ("POST", "/api/v1/users"): {"username": "new", "role": "viewer", "password": "pw-123456"},
        ("POST", "/api/v1/users/{user_id}/tokens"): {"name": "t", "ttl_hours": 1.0},
        ("PATCH", "/api/v1/users/{user_id}"): {"active": True},
        ("PUT", "/api/v1/me/password"): {
            "current_password": "admin-password",
            "new_password": "admin-password",
        },
        ("POST", "/api/v1/tokens/revoke"): {"device": "no-such-headset"},
        ("POST", "/api/v1/inspections"): inspection,
        ("PATCH", "/api/v1/inspections/{inspection_id}"): inspection,
        ("POST", "/api/v1/tolerance-sets"): {"name": "n", "tolerances": TOLERANCES},
        ("PATCH", "/api/v1/tolerance-sets/{set_id}"): {"tolerances": TOLERANCES},
        ("POST", "/api/v1/inspections/{inspection_id}/tolerance-set"): {"set_id": ids["set_id"]},
        ("POST", "/api/v1/inspections/{inspection_id}/runs"): {
            "steps": [{"name": "m", "kind": "measure", "inputs": [ids["artifact_id"]]}]  # alias
        },
        ("POST", "/api/v1/defects"): {
            "inspection_id": ids["inspection_id"],
            "type": "dent",
            "location_mm": [1.0, 2.0, 3.0],
            "normal": [0.0, 0.0, 1.0],
            "value_mm": 0.3,
            "tolerance_mm": 0.2,
            "extent_mm": 4.0,
            "confidence": 0.9,
        },
        ("PATCH", "/api/v1/defects/{defect_id}"): {"status": "open"},
        ("POST", "/api/v1/defects/{defect_id}/notes"): {"text": "a note"},
        ("PUT", "/api/v1/defects/{defect_id}/judgments/me"): {"verdict": "confirmed"},
        ("POST", "/api/v1/sync/judgments"): {
            "items": [
                {
                    "client_id": "c-1",
                    "defect_id": ids["defect_id"],
                    "verdict": "confirmed",
                    "client_time": "2026-01-01T00:00:00Z",
                }
            ]
        },
    }


def _resolve(schema: dict, root: dict) -> dict:
    """``schema`` with its ``$ref`` ("#/components/schemas/X", "#/$defs/X") followed."""
    while "$ref" in schema:
        target = root
        for key in schema["$ref"].removeprefix("#/").split("/"):
            target = target[key]
        schema = target
    return schema


def _number_paths(schema: dict, spec: dict, path: tuple = ()) -> list[tuple]:
    """Every place in a body the schema lets hold a number: (key or index, …)."""
    schema = _resolve(schema, spec)
    found = []
    for option in schema.get("anyOf", []) + schema.get("allOf", []):
        found += _number_paths(option, spec, path)
    kind = schema.get("type")
    if kind in ("number", "integer"):
        found.append(path)
    for key, sub in schema.get("properties", {}).items():
        found += _number_paths(sub, spec, (*path, key))
    for index, sub in enumerate(schema.get("prefixItems", [])):
        found += _number_paths(sub, spec, (*path, index))
    if "items" in schema and not schema.get("prefixItems"):
        found += _number_paths(schema["items"], spec, (*path, 0))
        found += _number_paths(schema["items"], spec, (*path, -1))
    return sorted(set(found), key=str)


def _with(body: object, path: tuple, raw: str) -> str:
    """The body as JSON text with the value at ``path`` replaced by the literal ``raw``."""
    copy = json.loads(json.dumps(body))
    node = copy
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = "__number__"
    return json.dumps(copy).replace('"__number__"', raw)


def _row_counts(runtime) -> dict[str, int]:
    with runtime.db.read() as session:
        return {
            t.name: session.scalar(select(func.count()).select_from(t))
            for t in Base.metadata.sorted_tables
        }


@pytest.fixture
def seeded(client, tokens, tmp_path):
    headers = auth(tokens["admin"])
    inspection = client.post(
        "/api/v1/inspections", json={"title": "numbers", "area": "cabin"}, headers=headers
    ).json()
    artifacts = {}
    from services.lib.pointcloud.stl import write_stl
    from tests.test_mesh_distance import box_mesh

    write_stl(tmp_path / "nominal.stl", box_mesh(np.array([10.0, 10.0, 2.0])))
    for kind, content in (
        ("cloud", ply_bytes(tmp_path)),
        ("nominal", (tmp_path / "nominal.stl").read_bytes()),
        ("scan", ply_bytes(tmp_path)),
        ("pairs", b"{}"),
        ("scans", b"{}"),
        ("handeye", b"{}"),
        (
            "frames",
            pack(small_sequence(tmp_path / "seq", seconds=0.05), tmp_path / "seq.zip").read_bytes(),
        ),
        ("drive", pack_drive(small_drive(tmp_path / "drive"), tmp_path / "drive.tgz").read_bytes()),
        ("model", tiny_depth_model(tmp_path / "depth.onnx").read_bytes()),
        ("image", (tmp_path / "drive" / "image_02" / "0000000000.png").read_bytes()),
        (
            "lidar",
            pack_sequence(
                small_lidar_drive(tmp_path / "lidar", frames=2), tmp_path / "lidar.tar.gz"
            ).read_bytes(),
        ),
    ):
        artifacts[kind] = client.post(
            f"/api/v1/inspections/{inspection['id']}/artifacts",
            params={"kind": kind, "name": f"{kind}.file"},
            content=content,
            headers={**headers, "content-type": "application/octet-stream"},
        ).json()["id"]
    defect = client.post(
        "/api/v1/defects",
        json={"inspection_id": inspection["id"], "type": "dent", "location_mm": [0, 0, 0]},
        headers=headers,
    ).json()
    me = client.get("/api/v1/me", headers=headers).json()
    tolerance_set = client.post(
        "/api/v1/tolerance-sets", json={"name": "numbers", "tolerances": {}}, headers=headers
    ).json()
    return {
        "set_id": tolerance_set["id"],
        "inspection_id": inspection["id"],
        "artifact_id": artifacts["cloud"],
        "artifacts": artifacts,
        "defect_id": defect["id"],
        "user_id": me["id"],
    }


def _refuses_every_bad_number(client, runtime, request: tuple, body: dict, paths) -> int:
    """Send ``body`` with each of ``paths`` set to each bad number: a 422 naming the field
    and nothing stored, every time. Returns how many requests were tried."""
    method, url, headers = request
    valid = client.request(method, url, content=json.dumps(body), headers=headers)
    assert valid.status_code < 300, (url, valid.text)  # the base body is right
    tried = 0
    for path in paths:
        for raw in BAD_NUMBERS:
            before = _row_counts(runtime)
            answer = client.request(method, url, content=_with(body, path, raw), headers=headers)
            where = ".".join(map(str, path))
            assert answer.status_code == 422, (method, url, where, raw, answer.text)
            name = next(str(k) for k in reversed(path) if isinstance(k, str))
            assert name in answer.json()["detail"], (url, where, answer.json())
            assert not PYDANTIC.search(answer.json()["detail"]), answer.json()["detail"]
            assert _row_counts(runtime) == before, (url, where, raw)
            tried += 1
    return tried


def _needed(spec: dict, params: dict, schema: dict) -> bool:
    """Whether a step with these params must be given an input of this spec (its minimum,
    or a parameter's value that needs one, the default when not given)."""
    if spec["min"]:
        return True
    if not spec["needed_when"]:
        return False
    name, values = spec["needed_when"]
    return params.get(name, schema["properties"][name].get("default")) in values


def test_every_number_field_refuses_non_finite_and_extreme_values(client, tokens, runtime, seeded):
    spec = client.get("/api/v1/openapi.json").json()
    bodies = _bodies(seeded)
    headers = {**auth(tokens["admin"]), "content-type": "application/json"}
    tried = 0
    for route, operations in spec["paths"].items():
        for method, operation in operations.items():
            key = (method.upper(), route)
            content = operation.get("requestBody", {}).get("content", {})
            if "application/json" not in content or key in NOT_JSON:
                continue
            assert key in bodies, f"{key}: give the test a valid body for this operation"
            paths = _number_paths(content["application/json"]["schema"], spec)
            request = (method, route.format(**seeded), headers)
            tried += _refuses_every_bad_number(client, runtime, request, bodies[key], paths)
    assert tried > 300
    # A run's params are free-form in the schema and checked against their job kind's.
    url = f"/api/v1/inspections/{seeded['inspection_id']}/runs"
    kinds = client.get("/api/v1/job-kinds", headers=headers).json()
    checked = 0
    for kind in kinds:
        paths = _number_paths(kind["params_schema"], kind["params_schema"])
        variants = REQUIRED_PARAMS.get(kind["name"], ({},))
        exclusive = set().union(*variants)
        for params in variants:
            inputs = [
                seeded["artifacts"][spec["kinds"][0]]
                for spec in kind["inputs"]
                if _needed(spec, params, kind["params_schema"])
            ]
            step = {"name": "s", "kind": kind["name"], "inputs": inputs, "params": params}
            steps = [
                ("steps", 0, "params", *path)
                for path in paths
                if path[0] in params or path[0] not in exclusive
            ]
            checked += _refuses_every_bad_number(
                client, runtime, ("POST", url, headers), {"steps": [step]}, steps
            )
    assert checked > 100
