"""``vista serve`` in its own process for a bench: started on a free port, waited for,
stopped."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx

SERVER_START_TIMEOUT_S = 60.0


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def server_environment(
    data_dir: Path, url: str, api_workers: int, extra: dict[str, str] | None = None
) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("VISTA_")}
    env.update(
        VISTA_DATA_DIR=str(data_dir),
        VISTA_DATABASE_URL=url,
        VISTA_EMBEDDED_WORKERS="0",
        VISTA_API_WORKERS=str(api_workers),
    )
    env.update(extra or {})
    return env


def wait_until_ready(process: subprocess.Popen, base_url: str, log_path: Path) -> None:
    deadline = time.monotonic() + SERVER_START_TIMEOUT_S
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(
                f"`vista serve` exited with code {process.returncode}:\n{_tail(log_path)}"
            )
        try:
            if httpx.get(f"{base_url}/readyz", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    raise RuntimeError(
        f"`vista serve` not ready after {SERVER_START_TIMEOUT_S:.0f} s:\n{_tail(log_path)}"
    )


def _tail(path: Path, lines: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no server log)"


def stop_process(process: subprocess.Popen) -> None:
    if process.poll() is not None:
        return
    process.terminate()
    try:
        process.wait(timeout=15)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=5)


@dataclass
class Server:
    port: int
    pid: int


@contextmanager
def running_server(
    data_dir: Path,
    url: str,
    api_workers: int,
    extra_env: dict[str, str] | None = None,
    cores: set[int] | None = None,
) -> Iterator[Server]:
    """``vista serve`` in its own process (no embedded workers unless ``extra_env`` sets
    VISTA_EMBEDDED_WORKERS), stopped on the way out; ``extra_env``: more VISTA_* settings;
    ``cores``: the CPUs it and its API processes run on (all when None)."""
    port = free_port()
    log_path = data_dir / "serve.log"
    command = [sys.executable, "-m", "supervisor.cli", "serve", "--port", str(port)]
    with log_path.open("wb") as log:
        process = subprocess.Popen(
            command,
            env=server_environment(data_dir, url, api_workers, extra_env),
            stdout=log,
            stderr=subprocess.STDOUT,
            preexec_fn=None if cores is None else lambda: os.sched_setaffinity(0, cores),
        )
    try:
        wait_until_ready(process, f"http://127.0.0.1:{port}", log_path)
        yield Server(port=port, pid=process.pid)
        if process.poll() is not None:
            raise RuntimeError(f"`vista serve` died during the bench:\n{_tail(log_path)}")
    finally:
        stop_process(process)
