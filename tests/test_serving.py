"""`vista serve --workers N`: balanced API processes that are restarted and stopped cleanly."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from supervisor.migrate import upgrade
from tests.conftest import free_port, wait_for


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(p) for p in path.read_text().split()] if path.exists() else []


def _api_processes(parent: int) -> list[int]:
    """The uvicorn processes (the spawn context adds a resource tracker beside them)."""
    return [p for p in _children(parent) if b"resource_tracker" not in _cmdline(p)]


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except FileNotFoundError:
        return b""


def _socket_inodes(pid: int) -> set[str]:
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except FileNotFoundError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    return inodes


def _established_inodes(port: int) -> set[str]:
    """Inodes of established TCP sockets whose local port is ``port``."""
    inodes = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        local_port = int(fields[1].split(":")[1], 16)
        if local_port == port and fields[3] == "01":  # 01 = ESTABLISHED
            inodes.add(fields[9])
    return inodes


@pytest.fixture
def served(tmp_path: Path):
    data = tmp_path / "data"
    data.mkdir()
    url = f"sqlite:///{data / 'vista.db'}"
    upgrade(url)
    port = free_port()
    log = (tmp_path / "serve.log").open("wb")
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("VISTA_")},
        "VISTA_DATA_DIR": str(data),
        "VISTA_DATABASE_URL": url,
        "VISTA_EMBEDDED_WORKERS": "0",
    }
    process = subprocess.Popen(
        [sys.executable, "-m", "supervisor.cli", "serve", "--port", str(port), "--workers", "2"],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    base = f"http://127.0.0.1:{port}"

    def ready() -> bool:
        try:
            return httpx.get(f"{base}/readyz", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    try:
        wait_for(lambda: len(_api_processes(process.pid)) == 2, what="two API processes")
        wait_for(ready, what="the API to answer")
        yield process, port, base
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        log.close()


def test_connections_spread_over_the_processes(served) -> None:
    process, port, base = served
    workers = _api_processes(process.pid)
    # Both processes answer: a process still starting keeps its connections queued.
    wait_for(lambda: all(_socket_inodes(p) for p in workers), what="sockets in both")
    clients = [socket.create_connection(("127.0.0.1", port)) for _ in range(32)]
    try:
        for sock in clients:
            sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
            assert sock.recv(1024).startswith(b"HTTP/1.1 200")
        established = _established_inodes(port)
        per_process = [len(_socket_inodes(p) & established) for p in workers]
    finally:
        for sock in clients:
            sock.close()
    assert sum(per_process) == 32
    assert min(per_process) >= 4, per_process  # all 32 on one of two: chance 2**-31


def test_a_killed_process_is_replaced_and_sigterm_stops_all(served) -> None:
    process, _port, base = served
    first, second = _api_processes(process.pid)
    os.kill(first, signal.SIGKILL)
    wait_for(
        lambda: len(set(_api_processes(process.pid)) - {first}) == 2,
        what="a replacement API process",
    )
    # the replacement's socket takes connections before its app has started: a request
    # the kernel gives it waits for that (a ceiling, not a speed check on a busy machine)
    for _ in range(20):
        assert httpx.get(f"{base}/healthz", timeout=120).status_code == 200
    workers = _api_processes(process.pid)
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=30) == 0
    assert all(not Path(f"/proc/{p}").exists() for p in workers)


def test_a_taken_port_is_a_clear_error(tmp_path: Path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    url = f"sqlite:///{data / 'vista.db'}"
    upgrade(url)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        env = {
            **{k: v for k, v in os.environ.items() if not k.startswith("VISTA_")},
            "VISTA_DATA_DIR": str(data),
            "VISTA_DATABASE_URL": url,
        }
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "supervisor.cli",
                "serve",
                "--port",
                str(port),
                "--workers",
                "2",
            ],
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert result.returncode == 2
    assert f"cannot listen on 127.0.0.1:{port}" in result.stderr + result.stdout


def test_api_processes_die_with_a_killed_parent(served) -> None:
    process, _port, _base = served
    workers = _api_processes(process.pid)
    process.kill()
    process.wait()
    wait_for(
        lambda: all(not Path(f"/proc/{p}").exists() or _zombie(p) for p in workers),
        what="the API processes to exit",
    )


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"
    except FileNotFoundError:
        return True
