"""Property-based testing of the whole API from its own OpenAPI document, with the
schemathesis CLI against a live server and a seeded database: no input causes a 5xx,
every response is one the document declares (status, media type, body, headers), and
requests are refused exactly when they break the schema (except where noted below)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import httpx

from tests.conftest import add_user, auth, make_settings
from tests.plyfiles import ply_bytes

CHECKS = (
    "not_a_server_error",
    "status_code_conformance",
    "content_type_conformance",
    "response_schema_conformance",
    "response_headers_conformance",
    "negative_data_rejection",
    "positive_data_acceptance",
)
# The SSE stream never ends for a job that never runs (run_engine=False here).
EXCLUDED_PATH = "/api/v1/jobs/{job_id}/events"


def _seed(server, token: str, tmp_path: Path) -> None:
    with httpx.Client(base_url=server.url, headers=auth(token), timeout=30) as http:
        inspection = http.post(
            "/api/v1/inspections", json={"title": "fuzz", "area": "cabin"}
        ).json()
        scan = http.post(
            f"/api/v1/inspections/{inspection['id']}/artifacts",
            params={"kind": "scan", "name": "s.ply"},
            content=ply_bytes(tmp_path),
            headers={"content-type": "application/x-ply"},
        ).json()
        http.post(
            f"/api/v1/inspections/{inspection['id']}/runs",
            json={"steps": [{"name": "inspect", "kind": "scan.inspect", "inputs": [scan["id"]]}]},
        )
        http.post(
            "/api/v1/defects",
            json={"inspection_id": inspection["id"], "type": "dent", "location_mm": [0, 0, 0]},
        )


def _config(server, runtime, admin_token: str) -> str:
    """schemathesis.toml: every request with the admin's token, except those that could
    end it: they get tokens of their own, or another user to change."""
    sign_out = add_user(runtime, "fuzz-sign-out", "inspector", "fuzz-password")
    revoker = add_user(runtime, "fuzz-revoker", "inspector", "fuzz-password")
    changed = add_user(runtime, "fuzz-changed", "viewer", "fuzz-password")
    changed_id = httpx.get(f"{server.url}/api/v1/me", headers=auth(changed)).json()["id"]
    checks = "\n".join(f"{check}.enabled = true" for check in CHECKS)
    return f"""
headers = {{ Authorization = "Bearer {admin_token}" }}

[checks]
enabled = false
{checks}
# In this API a 400 answers only what no schema can check: a `cursor` (or sync's `since`)
# this server did not give out; schema-valid data never has a body that is not UTF-8.
positive_data_acceptance.expected-statuses = [
    "2xx", "3xx", "400", "401", "403", "404", "409", "429", "5xx"
]

# The stateful phase sends values taken from responses, which need not be schema-valid
# requests (a defect's null `run_id` in /runs/{{run_id}}).
[phases.stateful]
checks.positive_data_acceptance.enabled = false

# Schema-valid requests these operations refuse (422), by rules no JSON Schema states:
# - a creating POST's Idempotency-Key used before with another body (all six);
# - inspections and tolerance sets: a gap range's min below its max (once merged with the
#   limits stored), a marker's transform rigid;
# - artifacts: the content being what `kind` needs; runs: the job kinds registered, their
#   params, the artifacts an inspection holds; defects: an inspection that exists;
# - what is stored: a user's role (no password for a device), a defect's status
#   (dismissing needs a reason) and type (not reclassified as itself).
[[operations]]
include-name = [
    "POST /api/v1/users",
    "POST /api/v1/inspections",
    "PATCH /api/v1/inspections/{{inspection_id}}",
    "POST /api/v1/tolerance-sets",
    "PATCH /api/v1/tolerance-sets/{{set_id}}",
    "POST /api/v1/inspections/{{inspection_id}}/artifacts",
    "POST /api/v1/inspections/{{inspection_id}}/runs",
    "POST /api/v1/defects",
    "PATCH /api/v1/users/{{user_id}}",
    "PATCH /api/v1/defects/{{defect_id}}",
    "PUT /api/v1/defects/{{defect_id}}/judgments/me",
]
checks.positive_data_acceptance.enabled = false

# Signing out revokes the token it is sent with.
[[operations]]
include-name = "DELETE /api/v1/auth/token"
headers = {{ Authorization = "Bearer {sign_out}" }}

# An admin may revoke any token, the fuzzer's too; an inspector only their own.
[[operations]]
include-name = "DELETE /api/v1/tokens/{{token_id}}"
headers = {{ Authorization = "Bearer {revoker}" }}

[[operations]]
include-name = "POST /api/v1/tokens/revoke"
headers = {{ Authorization = "Bearer {revoker}" }}

# Once another admin exists (POST /users makes some), the fuzzer could be deactivated or
# demoted: change another user only.
[[operations]]
include-name = "PATCH /api/v1/users/{{user_id}}"
parameters = {{ "path.user_id" = {changed_id} }}
"""


def test_the_api_answers_as_its_document_says(tmp_path, sqlite_url, start_server):
    server = start_server(make_settings(tmp_path, sqlite_url), run_engine=False)
    runtime = server.app.state.runtime
    token = add_user(runtime, "fuzzer", "admin", "fuzzer-password")
    _seed(server, token, tmp_path)
    config = tmp_path / "schemathesis.toml"
    config.write_text(_config(server, runtime, token))
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "schemathesis.cli",
            "--config-file",
            str(config),
            "run",
            f"{server.url}/api/v1/openapi.json",
            "--max-examples",
            "15",
            "--seed",
            "7",
            "--exclude-path",
            EXCLUDED_PATH,
            "--request-timeout",
            "30",
            "--no-color",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    report = result.stdout[-6000:] + result.stderr[-2000:]
    assert result.returncode == 0, report
    counts = re.search(r"(\d+) generated, (\d+) passed", result.stdout)
    assert counts, report
    generated, passed = map(int, counts.groups())
    assert generated == passed and generated >= 500, report
    me = httpx.get(f"{server.url}/api/v1/me", headers=auth(token))
    assert me.status_code == 200 and me.json()["role"] == "admin", "the fuzzer lost its token"
