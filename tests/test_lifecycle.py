"""Workers that live and die with their server, start-up that cleans what a crash left,
and durable writes (SQLite's synchronous level, fsynced artifact files)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import stat
import subprocess
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest
from sqlalchemy import text, update

from supervisor.db import Database
from supervisor.engine.context import JobClaim, StopSignal, WorkerContext, scratch_owner
from supervisor.engine.maintenance import STALE_TEMP_AGE_S, MaintenanceLoop
from supervisor.engine.runtime import Runtime
from supervisor.migrate import upgrade
from supervisor.models import Job
from supervisor.records import DomainRecords
from supervisor.storage import Storage
from tests.conftest import LiveServer, add_user, auth, free_port, make_settings, wait_for
from tests.jobkinds import SleepParams

REPO = Path(__file__).resolve().parent.parent


def _children(pid: int) -> list[int]:
    """Children of ``pid`` started by any of its threads (the kernel lists them by thread)."""
    children = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(FileNotFoundError):
            children += [int(p) for p in (task / "children").read_text().split()]
    return children


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except FileNotFoundError:
        return b""


def _gone(pid: int) -> bool:
    """Exited: no process, or a zombie nobody reaped (an orphan's new parent may not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def _embedded_workers(server: int) -> list[int]:
    """The server's job worker processes (spawned; the resource tracker is not one)."""
    return [
        pid
        for pid in _children(server)
        if b"multiprocessing.spawn" in _cmdline(pid) and b"resource_tracker" not in _cmdline(pid)
    ]


@pytest.fixture
def serve_env(tmp_path: Path) -> dict[str, str]:
    data = tmp_path / "data"
    data.mkdir()
    url = f"sqlite:///{data / 'vista.db'}"
    upgrade(url)
    return {
        **{k: v for k, v in os.environ.items() if not k.startswith("VISTA_")},
        "PYTHONPATH": str(REPO),
        "VISTA_DATA_DIR": str(data),
        "VISTA_DATABASE_URL": url,
        "VISTA_EMBEDDED_WORKERS": "2",
    }


def test_embedded_workers_exit_with_a_killed_server(serve_env: dict, tmp_path: Path) -> None:
    port = free_port()
    with (tmp_path / "serve.log").open("wb") as log:
        server = subprocess.Popen(
            [sys.executable, "-m", "supervisor.cli", "serve", "--port", str(port)],
            env=serve_env,
            cwd=REPO,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    workers: list[int] = []
    try:
        workers += wait_for(
            lambda: len(w := _embedded_workers(server.pid)) == 2 and w,
            what="two embedded workers",
        )
        wait_for(lambda: _ready(port), what="the API to answer")
        server.send_signal(signal.SIGKILL)
        server.wait()
        wait_for(lambda: all(_gone(p) for p in workers), timeout=5, what="the workers to exit")
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()
        for pid in workers:
            if not _gone(pid):
                os.kill(pid, signal.SIGKILL)


def _ready(port: int) -> bool:
    try:
        return httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


def _job_row(rt: Runtime, job_id: int) -> Job:
    with rt.db.read() as session:
        job = session.get(Job, job_id)
        assert job is not None
        return job


def _start_sleep_job(server: LiveServer, seconds: float) -> tuple[Runtime, httpx.Client, int]:
    rt = server.app.state.runtime
    http = httpx.Client(
        base_url=server.url, headers=auth(add_user(rt, "op", "inspector", "pw")), timeout=30
    )
    inspection = http.post("/api/v1/inspections", json={"title": "t", "area": "component"})
    step = {"name": "victim", "kind": "test.sleep", "params": {"seconds": seconds}, "after": []}
    run = http.post(f"/api/v1/inspections/{inspection.json()['id']}/runs", json={"steps": [step]})
    assert run.status_code == 201, run.text
    return rt, http, run.json()["jobs"][0]["id"]


def _kill_its_worker(rt: Runtime, job_id: int) -> float:
    """SIGKILL the worker running ``job_id`` once it made progress; when, monotonic s."""
    running = wait_for(
        lambda: (j := _job_row(rt, job_id)).status == "running" and j.progress > 0 and j,
        what="the job to make progress",
    )
    os.kill(int(running.worker.rsplit(":", 1)[1]), signal.SIGKILL)
    return time.monotonic()


def test_a_dead_workers_job_is_requeued_at_once(tmp_path: Path, sqlite_url: str, start_server):
    settings = make_settings(tmp_path, sqlite_url, embedded_workers=1, heartbeat_timeout_s=60.0)
    rt, http, job_id = _start_sleep_job(start_server(settings), seconds=1.5)
    killed = _kill_its_worker(rt, job_id)
    requeued = wait_for(
        lambda: (j := _job_row(rt, job_id)).status == "queued" and j,
        timeout=5,
        what="the job to be re-queued",
    )
    assert time.monotonic() - killed < 2.0  # not the heartbeat timeout of 60 s
    assert "exited (exit code -9, killed by SIGKILL) in attempt 1; re-queued" in requeued.message
    assert requeued.worker is None
    done = wait_for(
        lambda: (
            (j := http.get(f"/api/v1/jobs/{job_id}").json())["status"] != "queued"
            and j["status"] != "running"
            and j
        ),
        timeout=20,
        what="the job to end on the restarted worker",
    )
    assert (done["status"], done["attempts"], done["result"]["attempt"]) == ("succeeded", 2, 2)


def test_a_dead_workers_last_attempt_fails_at_once(tmp_path: Path, sqlite_url: str, start_server):
    settings = make_settings(
        tmp_path, sqlite_url, embedded_workers=1, heartbeat_timeout_s=60.0, job_max_attempts=1
    )
    rt, _http, job_id = _start_sleep_job(start_server(settings), seconds=5.0)
    killed = _kill_its_worker(rt, job_id)
    failed = wait_for(
        lambda: (j := _job_row(rt, job_id)).status == "failed" and j,
        timeout=5,
        what="the job to fail",
    )
    assert time.monotonic() - killed < 2.0
    assert "exited (exit code -9, killed by SIGKILL) in attempt 1 of 1;" in failed.error


def _age(path: Path, seconds: float) -> None:
    then = time.time() - seconds
    os.utime(path, (then, then))


def test_start_up_removes_what_killed_processes_left(
    tmp_path: Path, sqlite_url: str, runtime_factory, caplog: pytest.LogCaptureFixture
) -> None:
    client, tokens, rt = runtime_factory(make_settings(tmp_path, sqlite_url))
    headers = auth(tokens["inspector"])
    inspection = client.post(
        "/api/v1/inspections", json={"title": "t", "area": "component"}, headers=headers
    ).json()["id"]
    steps = [{"name": name, "kind": "test.sleep", "params": {}, "after": []} for name in ("a", "b")]
    run = client.post(
        f"/api/v1/inspections/{inspection}/runs", json={"steps": steps}, headers=headers
    ).json()
    running, ended = (j["id"] for j in run["jobs"])
    with rt.db.write() as session:  # job `running` is in its second attempt elsewhere
        session.execute(update(Job).where(Job.id == running).values(status="running", attempts=2))
    scratch = rt.scratch_dir
    keep = [scratch / f"job{running}-a2-live", scratch / "notes"]
    stale = [scratch / f"job{running}-a1-killed", scratch / f"job{ended}-a1-killed"]
    for folder in keep + stale:
        folder.mkdir(parents=True)
        (folder / "big.bin").write_bytes(b"x" * 1_000_000)
    old_part, fresh_part = rt.storage.new_temp_path(), rt.storage.new_temp_path()
    old_part.write_bytes(b"y" * 3_000_000)
    fresh_part.write_bytes(b"z")
    _age(old_part, STALE_TEMP_AGE_S + 60)
    _age(fresh_part, STALE_TEMP_AGE_S - 600)  # an upload stalled for 5 h 50 min may go on

    loop = MaintenanceLoop(rt)  # what a server (or a worker) starts with
    with caplog.at_level(logging.INFO, logger="vista.engine"):
        loop.start()
        wait_for(lambda: not old_part.exists(), timeout=5, what="the stale .part to go")
        loop.stop()
    assert fresh_part.exists() and all(folder.exists() for folder in keep)
    assert not any(folder.exists() for folder in stale)
    assert (
        "1 unfinished file(s) (3.0 MB)" in caplog.text
        and "2 scratch folder(s) of ended job attempts (2.0 MB)" in caplog.text
    )


def test_the_maintenance_loop_removes_a_killed_attempts_scratch_while_it_runs(
    tmp_path: Path, sqlite_url: str, runtime_factory
) -> None:
    """A scratch folder that appears after start-up (an attempt killed since) goes within
    a maintenance round, not at the next start only."""
    _, _, rt = runtime_factory(make_settings(tmp_path, sqlite_url))
    loop = MaintenanceLoop(rt)
    loop.start()
    try:
        # Filled beside the scratch folder and moved in at once: a round may run at any
        # moment, and it must not meet a half-made folder (it would remove it mid-write).
        staged = tmp_path / "job99-a1-killed"
        staged.mkdir()
        (staged / "big.bin").write_bytes(b"x" * 1000)
        rt.scratch_dir.mkdir(parents=True, exist_ok=True)
        killed = staged.rename(rt.scratch_dir / staged.name)
        wait_for(lambda: not killed.exists(), timeout=60, what="the killed attempt's scratch")
    finally:
        loop.stop()


def test_an_attempts_scratch_folder_is_private_and_named_by_its_owner(
    tmp_path: Path, sqlite_url: str
) -> None:
    rt = Runtime.create(make_settings(tmp_path, sqlite_url), records=DomainRecords())
    claim = JobClaim(
        id=7, kind="test.sleep", queue="test", step="s", run_id=1, inspection_id=1,
        params={}, attempt=3, max_attempts=3, inputs=(),
    )  # fmt: skip
    ctx = WorkerContext(rt, claim, SleepParams(), StopSignal())
    workdir = ctx.workdir
    assert workdir.parent == rt.scratch_dir and scratch_owner(workdir.name) == (7, 3)
    assert stat.S_IMODE(workdir.stat().st_mode) == 0o700
    ctx.close()
    assert not workdir.exists()
    rt.db.dispose()


@pytest.mark.parametrize(("setting", "level"), [(None, 2), ("FULL", 2), ("NORMAL", 1)])
def test_sqlite_syncs_every_commit_unless_told_otherwise(
    tmp_path: Path, sqlite_url: str, setting: str | None, level: int
) -> None:
    overrides = {} if setting is None else {"sqlite_synchronous": setting}
    rt = Runtime.create(make_settings(tmp_path, sqlite_url, **overrides), records=DomainRecords())
    with rt.db.read() as session:
        assert session.execute(text("PRAGMA synchronous")).scalar_one() == level
    rt.db.dispose()
    database = Database(sqlite_url)  # built from a URL alone: durable too
    with database.read() as session:
        assert session.execute(text("PRAGMA synchronous")).scalar_one() == 2
    database.dispose()


@pytest.fixture
def synced(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, ...]]:
    """The fsyncs and renames storage makes, in order, by path."""
    events: list[tuple[str, ...]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(source: os.PathLike, target: os.PathLike) -> None:
        real_replace(source, target)
        events.append(("replace", str(source), str(target)))

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    return events


def _assert_durable(events: list[tuple[str, ...]], root: Path, uri: str, storage: Storage):
    target = storage.path(uri)
    renames = [e for e in events if e[0] == "replace"]
    assert len(renames) == 1 and renames[0][2] == str(target)
    rename = events.index(renames[0])
    assert events[:rename].count(("fsync", renames[0][1])) == 1  # the file, before
    assert events[rename + 1 :] == [("fsync", str(target.parent))]  # its folder, after
    assert ("fsync", str(root / "inspections")) in events[:rename]  # the new folder's entry
    assert stat.S_IMODE(target.stat().st_mode) == 0o600
    for folder in (target.parent, root / "inspections", root / "tmp"):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700, folder


def test_a_stored_output_is_on_disk_before_its_row_commits(tmp_path: Path, synced) -> None:
    root = tmp_path / "artifacts"
    storage = Storage(root)
    source = tmp_path / "cloud.ply"
    source.write_bytes(b"ply\n" * 1000)
    stored = storage.put_file(source, inspection_id=1, name="cloud.ply")
    _assert_durable(synced, root, stored.uri, storage)
    synced.clear()
    stored = storage.put_bytes(b"{}", inspection_id=2, name="report.json")
    _assert_durable(synced, root, stored.uri, storage)


def test_an_upload_is_on_disk_before_its_row_commits(tmp_path: Path, synced) -> None:
    root = tmp_path / "artifacts"
    storage = Storage(root)

    async def chunks() -> AsyncIterator[bytes]:
        for _ in range(3):
            yield b"a" * 1000

    received = asyncio.run(storage.receive(chunks(), limit_bytes=10_000))
    assert stat.S_IMODE(storage.path(received.uri).stat().st_mode) == 0o600
    uri = storage.commit(received.uri, inspection_id=5, name="scan.ply")
    _assert_durable(synced, root, uri, storage)
