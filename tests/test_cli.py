from __future__ import annotations

import re
import subprocess
import sys

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from supervisor.app import create_app
from supervisor.cli import app
from supervisor.settings import get_settings


@pytest.fixture
def cli(tmp_path, monkeypatch):
    monkeypatch.setenv("VISTA_DATA_DIR", str(tmp_path / "data"))
    for name in ("VISTA_DATABASE_URL", "VISTA_BROKER_URL", "VISTA_ARTIFACT_DIR"):
        monkeypatch.delenv(name, raising=False)
    get_settings.cache_clear()
    runner = CliRunner()
    yield lambda *args: runner.invoke(app, list(args))
    get_settings.cache_clear()


def test_migrate_then_create_user_prints_a_working_token(cli, tmp_path):
    migrated = cli("migrate")
    assert migrated.exit_code == 0 and "is at migration" in migrated.output
    created = cli("user", "create", "ada", "--role", "admin")
    assert created.exit_code == 0, created.output
    token = created.output.strip()
    assert token.startswith("vst_")
    with TestClient(create_app(get_settings(), run_engine=False)) as client:
        me = client.get("/api/v1/me", headers={"Authorization": f"Bearer {token}"}).json()
    assert me["username"] == "ada" and me["role"] == "admin" and me["token_kind"] == "cli"
    again = cli("user", "create", "ada", "--role", "admin")
    assert again.exit_code == 2 and "already exists" in again.output


def test_cli_errors_are_sentences(cli):
    cli("migrate")
    bad_role = cli("user", "create", "bob", "--role", "boss")
    assert bad_role.exit_code == 2 and "--role must be one of" in bad_role.output
    no_broker = cli("worker", "--queues", "scan")
    assert no_broker.exit_code == 2 and "VISTA_BROKER_URL" in no_broker.output


def test_serve_creates_a_new_embedded_database_and_refuses_an_old_one(cli, tmp_path):
    from supervisor.migrate import check_schema, current_revision, head_revision, upgrade

    new = f"sqlite:///{tmp_path / 'new.db'}"
    created = check_schema(new)
    assert created.startswith("created the database") and "new.db" in created
    assert current_revision(new) == head_revision() and check_schema(new) is None
    get_settings().data_dir.mkdir(parents=True)
    upgrade(get_settings().resolved_database_url, "0001")  # an older vista's database
    refused = cli("serve")
    assert refused.exit_code == 2 and "run `vista migrate` first" in refused.output


def test_unknown_worker_queue_is_refused(cli, monkeypatch):
    monkeypatch.setenv("VISTA_BROKER_URL", "redis://127.0.0.1:6379/15")
    get_settings.cache_clear()
    refused = cli("worker", "--queues", "scan,paint")
    assert refused.exit_code == 2 and "unknown queue(s) ['paint']" in refused.output


COMPILES = """
from numba.core import event
from supervisor.engine.registry import declared_hooks

compiled = event.RecordingListener()
event.register("numba:compile", compiled)
for warm_up in declared_hooks("PRECOMPILE"):
    warm_up()
print(len(compiled.buffer) // 2)
"""


def test_precompile_leaves_nothing_to_compile_for_the_next_process():
    """`vista precompile` runs each service's small job; a process started after it
    compiles nothing for the same jobs: every kernel comes from numba's cache. (Fast after
    `make install`, which ran it; up to a minute after a kernel's source changed.)"""
    ran = subprocess.run(
        [sys.executable, "-m", "supervisor.cli", "precompile"],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    assert re.search(r"^defects: ready in \d+\.\d s$", ran.stdout, re.M), ran.stdout
    assert re.search(r"^odometry: ready in \d+\.\d s$", ran.stdout, re.M), ran.stdout
    again = subprocess.run(
        [sys.executable, "-c", COMPILES], capture_output=True, text=True, timeout=600, check=True
    )
    assert again.stdout.split()[-1] == "0", again.stdout


def test_demo_runs_the_whole_chain_and_shows_findings(cli, tmp_path):
    shown = cli("demo", "--spacing-mm", "0.3", "--timeout", "300")
    assert shown.exit_code == 0, shown.output
    assert "calibrate succeeded 100%, stitch succeeded 100%, measure succeeded 100%" in shown.output
    assert "“Demo: cabin sidewall lining”" in shown.output
    for kind in ("dent", "bump", "scratch", "color"):
        assert f" {kind} " in shown.output, kind
    last = shown.output.strip().splitlines()[-2:]
    assert "open the dashboard at http://" in last[0] and "/docs (works offline)" in last[1]
    assert "Warning" not in shown.output
    assert "(tolerance " not in shown.output and " mm (limits ≤ 0.30 mm) " in shown.output
    # the findings are the inspection's: a reviewer signing in with the printed password
    # sees them; no published password works
    password = re.search(r"sign in as demo with the password (\S+) ", shown.output).group(1)
    with TestClient(create_app(get_settings(), run_engine=False)) as client:
        published = {"username": "demo", "password": "vista-demo"}
        assert client.post("/api/v1/auth/token", json=published).status_code == 401
        signed_in = client.post(
            "/api/v1/auth/token", json={"username": "demo", "password": password}
        )
        assert signed_in.status_code in (200, 201), signed_in.text
        client.headers["authorization"] = f"Bearer {signed_in.json()['access_token']}"
        defects = client.get("/api/v1/defects", params={"inspection": 1, "limit": 200}).json()
    assert len([d for d in defects["items"] if d["severity"] != "info"]) >= 8
    # a second demo adds a second inspection, the demo user is reused
    again = cli(
        "demo", "--spacing-mm", "0.5", "--seed", "1", "--timeout", "300"
    )  # a coarser scan: quicker
    assert again.exit_code == 0 and "inspection 2 " in again.output


def test_every_service_has_its_simulator_and_its_bench(cli):
    """The README's `vista <service> simulate` and `vista <service> bench`: each service
    lists them; the older `vista simulate <service>` still runs, hidden from the list."""
    for service in ("defects", "stitching", "odometry", "depth", "tracking"):
        listed = cli(service, "--help").output
        assert " simulate " in listed and " bench " in listed, (service, listed)
    assert not any(
        line.strip("│ ").startswith("simulate ") for line in cli("--help").output.splitlines()
    )
    older = cli("simulate", "defects", "--help")
    assert older.exit_code == 0 and "--spacing-mm" in older.output


def test_the_shared_data_folder_is_a_setting(monkeypatch, tmp_path):
    """The benches and the default models' builds find the real data where
    VISTA_SHARED_DATA says, else beside the checkout."""
    from services.lib.shared_data import DEFAULT_SHARED_DATA, shared_data_dir

    monkeypatch.delenv("VISTA_SHARED_DATA", raising=False)
    assert shared_data_dir() == DEFAULT_SHARED_DATA
    assert DEFAULT_SHARED_DATA.parts[-2:] == ("shared", "data")
    monkeypatch.setenv("VISTA_SHARED_DATA", str(tmp_path))
    assert shared_data_dir() == tmp_path
