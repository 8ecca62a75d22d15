"""Property-based fuzzing of the whole API from its own OpenAPI schema: no input may
cause a 5xx. Runs the schemathesis CLI against a live server with a seeded database."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from tests.conftest import add_user, auth, make_settings
from tests.plyfiles import ply_bytes

# The SSE stream never ends for a job that never runs (run_engine=False here).
EXCLUDED_PATH = "/api/v1/jobs/{job_id}/events"


def _seed(server, token: str, tmp_path: Path) -> None:
    import httpx

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


def test_no_input_causes_a_server_error(tmp_path, sqlite_url, start_server):
    server = start_server(make_settings(tmp_path, sqlite_url), run_engine=False)
    token = add_user(server.app.state.runtime, "fuzzer", "admin", "fuzzer-password")
    _seed(server, token, tmp_path)
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "schemathesis.cli",
            "run",
            f"{server.url}/api/v1/openapi.json",
            "--checks",
            "not_a_server_error",
            "--header",
            f"Authorization: Bearer {token}",
            "--max-examples",
            "30",
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
    )
    report = result.stdout[-6000:] + result.stderr[-2000:]
    assert result.returncode == 0, report
    counts = re.search(r"(\d+) generated, (\d+) passed", result.stdout)
    assert counts, report
    generated, passed = map(int, counts.groups())
    assert generated == passed and generated >= 500, report
