"""Fixtures: a migrated database per test (SQLite always, PostgreSQL when configured),
the API in-process or as a live server, users with tokens, real worker processes."""

from __future__ import annotations

import os
import shutil
import socket
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from datetime import timedelta
from pathlib import Path

import httpx
import pytest
import uvicorn
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

from supervisor.app import create_app
from supervisor.auth.service import hash_password
from supervisor.db import Base
from supervisor.engine.runtime import Runtime
from supervisor.migrate import upgrade
from supervisor.records import DomainRecords
from supervisor.settings import Settings
from supervisor.users.service import create_token, create_user

PG_URL = os.environ.get("VISTA_TEST_DATABASE_URL")
BROKER_URL = os.environ.get("VISTA_TEST_BROKER_URL")
NO_POSTGRES = "PostgreSQL not configured: set VISTA_TEST_DATABASE_URL (.ci/run does)"
NO_BROKER = "Redis/RabbitMQ not configured: set VISTA_TEST_BROKER_URL (.ci/run does)"


def pytest_configure(config: pytest.Config) -> None:
    if os.environ.get("VISTA_TEST_REQUIRE_SERVERS") == "1" and not (PG_URL and BROKER_URL):
        raise pytest.UsageError("VISTA_TEST_REQUIRE_SERVERS=1 needs both test server URLs")
    # Each test process counts its own cloud readers: a fuzz test's conversions on one
    # worker must not make another worker's upload wait for a slot (429).
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    slots = Path(tempfile.gettempdir()) / f"vista-test-readers-{os.getpid()}-{worker}"
    os.environ["VISTA_READER_SLOTS_DIR"] = str(slots)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Iterator[None]:
    """Where CI runs (``VISTA_TEST_REQUIRE_SERVERS=1``, set by .ci/run, which also checks
    that ``../shared/data`` is there) a skipped test fails, naming what it lacked: CI
    never passes with a test that did not run."""
    outcome = yield
    report = outcome.get_result()
    if (
        os.environ.get("VISTA_TEST_REQUIRE_SERVERS") == "1"
        and report.skipped
        and not hasattr(report, "wasxfail")
    ):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else report.longrepr
        report.outcome = "failed"
        report.longrepr = f"skipped where CI requires every test to run: {reason}"


@pytest.fixture(scope="session")
def sqlite_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("template") / "vista.db"
    upgrade(f"sqlite:///{path}")
    return path


@pytest.fixture(scope="session")
def pg_database() -> Iterator[str]:
    """A fresh PostgreSQL database for this test session, built by the migrations."""
    if not PG_URL:
        pytest.skip(NO_POSTGRES)
    name = f"vista_test_{uuid.uuid4().hex[:10]}"
    admin = create_engine(PG_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    url = make_url(PG_URL).set(database=name).render_as_string(hide_password=False)
    upgrade(url)
    yield url
    with admin.connect() as connection:
        connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    admin.dispose()


def _truncate(url: str) -> None:
    tables = ", ".join(t.name for t in Base.metadata.sorted_tables)
    engine = create_engine(url)
    with engine.begin() as connection:
        connection.execute(text(f"TRUNCATE {tables} RESTART IDENTITY CASCADE"))
    engine.dispose()


def _database_url(kind: str, request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if kind == "sqlite":
        path = tmp_path / "vista.db"
        shutil.copy(request.getfixturevalue("sqlite_template"), path)
        return f"sqlite:///{path}"
    url = request.getfixturevalue("pg_database")
    _truncate(url)
    return url


@pytest.fixture(params=["sqlite", "postgres"])
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    return _database_url(request.param, request, tmp_path)


@pytest.fixture
def sqlite_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    return _database_url("sqlite", request, tmp_path)


@pytest.fixture
def postgres_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    return _database_url("postgres", request, tmp_path)


def make_settings(tmp_path: Path, database_url: str, **overrides) -> Settings:
    values = dict(
        data_dir=tmp_path / "data",
        database_url=database_url,
        broker_url=None,
        embedded_workers=0,
        heartbeat_interval_s=0.3,
        heartbeat_timeout_s=3.0,
        retry_backoff_s=0.2,
        extra_job_kinds=["tests.jobkinds"],
    )
    values.update(overrides)
    return Settings(**values)


@pytest.fixture
def settings(tmp_path: Path, database_url: str) -> Settings:
    return make_settings(tmp_path, database_url)


@pytest.fixture
def runtime(settings: Settings) -> Iterator[Runtime]:
    rt = Runtime.create(settings, records=DomainRecords())
    yield rt
    rt.db.dispose()


@pytest.fixture
def client(settings: Settings, runtime: Runtime) -> Iterator[TestClient]:
    with TestClient(create_app(settings, runtime=runtime, run_engine=False)) as test_client:
        yield test_client


def add_user(runtime: Runtime, username: str, role: str, password: str | None = None) -> str:
    with runtime.db.write() as session:
        password_hash = hash_password(password) if password else None
        user = create_user(session, username=username, role=role, password_hash=password_hash)
        kind = "device" if role == "device" else "cli"
        return create_token(session, user=user, name="test", kind=kind, ttl=timedelta(days=1))


@pytest.fixture
def tokens(runtime: Runtime) -> dict[str, str]:
    return {
        "admin": add_user(runtime, "ada", "admin", "admin-password"),
        "inspector": add_user(runtime, "ines", "inspector", "inspector-password"),
        "inspector2": add_user(runtime, "ivan", "inspector", "inspector-password"),
        "viewer": add_user(runtime, "vic", "viewer", "viewer-password"),
        "device": add_user(runtime, "hololens-1", "device"),
    }


@pytest.fixture
def runtime_factory():  # a factory of (client, tokens, runtime)
    """For tests that need settings of their own (e.g. a small upload limit)."""
    opened: list[tuple[TestClient, Runtime]] = []

    def open_app(settings: Settings) -> tuple[TestClient, dict[str, str], Runtime]:
        rt = Runtime.create(settings, records=DomainRecords())
        test_client = TestClient(create_app(settings, runtime=rt, run_engine=False))
        test_client.__enter__()
        opened.append((test_client, rt))
        return test_client, {"inspector": add_user(rt, "ines", "inspector", "inspector-pw")}, rt

    yield open_app
    for test_client, rt in opened:
        test_client.__exit__(None, None, None)
        rt.db.dispose()


def auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class LiveServer:
    """A real uvicorn server in a thread, on a free loopback port."""

    def __init__(self, settings: Settings, runtime: Runtime, run_engine: bool) -> None:
        app = create_app(settings, runtime=runtime, run_engine=run_engine)
        self.runtime = runtime
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.app = app
        config = uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning")
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._server.run, daemon=True)

    def start(self) -> LiveServer:
        self._thread.start()
        deadline = time.monotonic() + 30
        while not self._server.started:
            if time.monotonic() > deadline or not self._thread.is_alive():
                raise RuntimeError("the live server did not start")
            time.sleep(0.05)
        return self

    def stop(self) -> None:
        self._server.should_exit = True
        self._thread.join(timeout=30)


@pytest.fixture
def start_server(tmp_path: Path) -> Iterator[Callable[..., LiveServer]]:
    started: list[tuple[LiveServer, Runtime]] = []

    def start(settings: Settings, *, run_engine: bool = True) -> LiveServer:
        rt = Runtime.create(settings, records=DomainRecords())
        server = LiveServer(settings, rt, run_engine).start()
        started.append((server, rt))
        return server

    yield start
    for server, rt in started:
        server.stop()
        rt.db.dispose()


@pytest.fixture
def live_api(start_server, tmp_path: Path, sqlite_url: str) -> tuple[LiveServer, Runtime, str]:
    """An API served on SQLite without its engine, its runtime, and the admin ada's token
    (password admin-pw); a test adds the other users it needs with ``add_user``."""
    server = start_server(make_settings(tmp_path, sqlite_url), run_engine=False)
    return server, server.runtime, add_user(server.runtime, "ada", "admin", "admin-pw")


def wait_for(predicate: Callable[[], object], *, timeout: float = 30.0, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def job_status(base_url: str, token: str, job_id: int) -> dict:
    return httpx.get(f"{base_url}/api/v1/jobs/{job_id}", headers=auth(token), timeout=10).json()
