"""``vista bench api``: the API under load, against a real ``vista serve`` process.

For SQLite (always) and PostgreSQL (when a server URL is given), on a fresh database:

* **judgment writes** — ``clients`` concurrent reviewers each PUT their own judgment on
  defects they share with the others, every PUT changing something; writes/s and the
  p50/p99 latency after a warm-up;
* **integrity** — afterwards, straight from the database: one ``judgments`` row per
  (user, defect), its ``revision`` equal to the writes that client saw succeed, and the
  history exactly revisions 1..N (nothing lost, nothing duplicated);
* **defect pages** — 100-item pages out of ``defects`` at random cursors, one client.

The load generator is a tiny keep-alive HTTP/1.1 client on one event loop, so it takes as
little of the machine's CPU from the server as it can; its own CPU time is reported.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import platform
import random
import secrets
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Coroutine, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy import create_engine, func, insert, select, text
from sqlalchemy.engine import make_url

from supervisor.db import Database, make_engine
from supervisor.migrate import upgrade
from supervisor.models import Change, Defect, Inspection, Judgment, JudgmentRevision
from supervisor.models.defects import DEFECT_TYPES, SEVERITIES
from supervisor.pagination import encode_cursor
from supervisor.users.service import create_token, create_user

TARGETS = {
    "writes_per_s_min": 300.0,
    "write_p99_ms_max": 100.0,
    "page_p50_ms_max": 20.0,
    "lost": 0,
    "duplicated": 0,
}
WARMUP_S = 1.0
HOT_DEFECTS = 500
PAGE_SIZE = 100
PAGE_REQUESTS = 200
PAGE_WARMUP_REQUESTS = 10
VERDICT_CYCLE = ("confirmed", "rejected", "uncertain")
REQUEST_TIMEOUT_S = 30.0
SERVER_START_TIMEOUT_S = 60.0
SEED = 20240601


def _say(message: str) -> None:
    print(f"[bench api] {message}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- HTTP client


class RawHttp:
    """One keep-alive HTTP/1.1 connection, just enough for JSON requests to uvicorn.

    httpx costs several times more CPU per request; on a 2-core machine that CPU would
    come out of the server being measured."""

    def __init__(self, host: str, port: int, token: str) -> None:
        self.host, self.port = host, port
        self._static = (
            f"Host: {host}:{port}\r\nAuthorization: Bearer {token}\r\nAccept: application/json\r\n"
        )
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def connect(self) -> None:
        self._reader, self._writer = await asyncio.open_connection(self.host, self.port)
        sock = self._writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    async def close(self) -> None:
        writer, self._reader, self._writer = self._writer, None, None
        if writer is not None:
            writer.close()
            with suppress(OSError):
                await writer.wait_closed()

    async def request(self, method: str, path: str, body: bytes | None = None) -> tuple[int, bytes]:
        if self._writer is None:
            await self.connect()
        assert self._reader is not None and self._writer is not None
        head = f"{method} {path} HTTP/1.1\r\n{self._static}"
        if body is not None:
            head += f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
        self._writer.write(head.encode() + b"\r\n" + (body or b""))
        status, length, close = await self._read_head(self._reader)
        payload = await self._reader.readexactly(length) if length else b""
        if close:
            await self.close()
        return status, payload

    @staticmethod
    async def _read_head(reader: asyncio.StreamReader) -> tuple[int, int, bool]:
        status_line = await reader.readline()
        if not status_line:
            raise ConnectionError("the server closed the connection")
        status = int(status_line.split(b" ", 2)[1])
        length, close = 0, False
        while True:
            line = await reader.readline()
            if line in (b"\r\n", b"\n", b""):
                return status, length, close
            name, _, value = line.partition(b":")
            name = name.strip().lower()
            if name == b"content-length":
                length = int(value)
            elif name == b"connection":
                close = value.strip().lower() == b"close"
            elif name == b"transfer-encoding":
                raise ValueError("chunked responses are not supported by the bench client")


def _run_async(coroutine: Coroutine[Any, Any, Any]) -> Any:
    """Run on uvloop when it is installed (less load-generator CPU)."""
    factory: Callable[[], asyncio.AbstractEventLoop] | None = None
    try:
        import uvloop

        factory = uvloop.new_event_loop
    except ImportError:  # pragma: no cover - uvloop comes with uvicorn[standard]
        pass
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(coroutine)


# --------------------------------------------------------------------------- statistics


def percentile(values: list[float], q: float) -> float | None:
    """Nearest-rank percentile, ``q`` in 0..100; None for no values."""
    if not values:
        return None
    ordered = sorted(values)
    rank = max(1, math.ceil(q / 100 * len(ordered)))
    return ordered[min(rank, len(ordered)) - 1]


def latency_summary(latencies_ms: list[float]) -> dict[str, float | None]:
    def rounded(value: float | None) -> float | None:
        return None if value is None else round(value, 3)

    return {
        "p50_ms": rounded(percentile(latencies_ms, 50)),
        "p90_ms": rounded(percentile(latencies_ms, 90)),
        "p99_ms": rounded(percentile(latencies_ms, 99)),
        "max_ms": rounded(max(latencies_ms) if latencies_ms else None),
        "mean_ms": rounded(sum(latencies_ms) / len(latencies_ms) if latencies_ms else None),
    }


def _process_tree(pid: int) -> list[int]:
    """``pid`` and its descendants (Linux /proc)."""
    tree, frontier = [], [pid]
    while frontier:
        current = frontier.pop()
        tree.append(current)
        for task in Path(f"/proc/{current}/task").glob("*/children"):
            with suppress(OSError):
                frontier.extend(int(child) for child in task.read_text().split())
    return tree


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a process and its children (Linux /proc), None elsewhere."""
    total = 0.0
    try:
        for member in _process_tree(pid):
            fields = Path(f"/proc/{member}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except OSError:
        return None
    return total


def system_cpu_ticks() -> tuple[int, int] | None:
    """(busy, total) jiffies of the whole machine (Linux /proc/stat), None elsewhere."""
    try:
        values = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    except (OSError, ValueError, IndexError):
        return None
    idle = values[3] + (values[4] if len(values) > 4 else 0)
    return sum(values) - idle, sum(values)


def busy_percent(before: tuple[int, int] | None, after: tuple[int, int] | None) -> float | None:
    if before is None or after is None or after[1] == before[1]:
        return None
    return round(100 * (after[0] - before[0]) / (after[1] - before[1]), 1)


# --------------------------------------------------------------------------- databases


@contextmanager
def fresh_postgres_database(server_url: str) -> Iterator[str]:
    """A new, empty database on the server of ``server_url``; dropped afterwards."""
    name = f"vista_bench_{secrets.token_hex(5)}"
    admin = create_engine(server_url, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as connection:
            connection.execute(text(f'CREATE DATABASE "{name}"'))
        try:
            yield make_url(server_url).set(database=name).render_as_string(hide_password=False)
        finally:
            with admin.connect() as connection:
                connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    finally:
        admin.dispose()


@dataclass
class Seeded:
    admin_token: str
    inspection_id: int
    user_ids: list[int]
    user_tokens: list[str]
    defect_ids: list[int]


def defect_rows(inspection_id: int, count: int, rng: random.Random) -> list[dict[str, Any]]:
    """Plausible, varied defects: every type and severity, spread over a fuselage section."""
    now = datetime.now(UTC)
    rows = []
    for i in range(count):
        kind = DEFECT_TYPES[i % len(DEFECT_TYPES)]
        tolerance = round(rng.uniform(0.2, 2.0), 3)
        rows.append(
            {
                "inspection_id": inspection_id,
                "run_id": None,
                "job_id": None,
                "type": kind,
                "status": "open",
                "value_mm": round(tolerance * rng.uniform(1.05, 3.0), 3),
                "tolerance_mm": tolerance,
                "measurements": {"samples": rng.randint(3, 400), "method": "bench"},
                "location_mm": [
                    round(rng.uniform(0, 12_000), 2),
                    round(rng.uniform(-2_000, 2_000), 2),
                    round(rng.uniform(0, 2_500), 2),
                ],
                "normal": [0.0, 0.0, 1.0],
                "extent_mm": round(rng.uniform(0, 80), 2),
                "severity": SEVERITIES[rng.randrange(len(SEVERITIES))],
                "confidence": round(rng.uniform(0.5, 1.0), 3),
                "source": "bench",
                "created_at": now,
            }
        )
    return rows


def seed_database(url: str, *, clients: int, defects: int, rng: random.Random) -> Seeded:
    """Users with tokens, one inspection and its defects, written straight to the database."""
    db = Database(url)
    try:
        with db.write() as session:
            admin = create_user(session, username="bench-admin", role="admin", password=None)
            admin_token = create_token(
                session, user=admin, name="bench", kind="cli", ttl_hours=None
            )
            user_ids, user_tokens = [], []
            for index in range(clients):
                user = create_user(
                    session,
                    username=f"bench-inspector-{index:03d}",
                    role="inspector",
                    password=None,
                )
                user_tokens.append(
                    create_token(session, user=user, name="bench", kind="cli", ttl_hours=None)
                )
                user_ids.append(user.id)
            inspection = Inspection(
                title="bench api",
                aircraft="A320",
                serial="MSN-BENCH",
                area="cargo",
                tolerances={},
                status="review",
                created_by=admin.id,
            )
            session.add(inspection)
            session.flush()
            inspection_id = inspection.id
            if defects:
                session.execute(insert(Defect), defect_rows(inspection_id, defects, rng))
        with db.read() as session:
            defect_ids = list(
                session.scalars(
                    select(Defect.id)
                    .where(Defect.inspection_id == inspection_id)
                    .order_by(Defect.id)
                )
            )
    finally:
        db.dispose()
    return Seeded(admin_token, inspection_id, user_ids, user_tokens, defect_ids)


# --------------------------------------------------------------------------- server


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def server_environment(data_dir: Path, url: str, api_workers: int) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("VISTA_")}
    env.update(
        VISTA_DATA_DIR=str(data_dir),
        VISTA_DATABASE_URL=url,
        VISTA_EMBEDDED_WORKERS="0",
        VISTA_API_WORKERS=str(api_workers),
    )
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
def running_server(data_dir: Path, url: str, api_workers: int) -> Iterator[Server]:
    """``vista serve`` in its own process (no embedded workers), stopped on the way out."""
    port = free_port()
    log_path = data_dir / "serve.log"
    command = [sys.executable, "-m", "supervisor.cli", "serve", "--port", str(port)]
    with log_path.open("wb") as log:
        process = subprocess.Popen(
            command,
            env=server_environment(data_dir, url, api_workers),
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    try:
        wait_until_ready(process, f"http://127.0.0.1:{port}", log_path)
        yield Server(port=port, pid=process.pid)
        if process.poll() is not None:
            raise RuntimeError(f"`vista serve` died during the bench:\n{_tail(log_path)}")
    finally:
        stop_process(process)


# --------------------------------------------------------------------------- write test


@dataclass
class WriterLog:
    """What one client did: its latencies and, per defect, how many writes it saw land."""

    user_id: int
    latencies_ms: list[float] = field(default_factory=list)
    measured_ok: int = 0
    measured_errors: int = 0
    errors: int = 0
    statuses: Counter = field(default_factory=Counter)
    succeeded: dict[int, int] = field(default_factory=lambda: defaultdict(int))
    failed: dict[int, int] = field(default_factory=lambda: defaultdict(int))
    revision_mismatches: int = 0
    last_done: float = 0.0


def judgment_body(client: int, counter: int) -> bytes:
    """A judgment different from this client's previous one on any defect."""
    verdict = VERDICT_CYCLE[counter % len(VERDICT_CYCLE)]
    return json.dumps({"verdict": verdict, "comment": f"bench c{client} #{counter}"}).encode()


async def put_judgment(http: RawHttp, defect_id: int, body: bytes) -> tuple[int, bytes]:
    try:
        return await asyncio.wait_for(
            http.request("PUT", f"/api/v1/defects/{defect_id}/judgments/me", body),
            REQUEST_TIMEOUT_S,
        )
    except (OSError, TimeoutError, ValueError, IndexError, asyncio.IncompleteReadError):
        await http.close()
        return 0, b""


async def run_writer(
    index: int,
    http: RawHttp,
    log: WriterLog,
    hot_defects: list[int],
    measure_from: float,
    stop_at: float,
) -> None:
    rng = random.Random(SEED + index)
    counter = 0
    while time.perf_counter() < stop_at:
        defect_id = rng.choice(hot_defects)
        counter += 1
        started = time.perf_counter()
        status, payload = await put_judgment(http, defect_id, judgment_body(index, counter))
        done = time.perf_counter()
        measured = started >= measure_from
        log.statuses[status] += 1
        if 200 <= status < 300:
            log.succeeded[defect_id] += 1
            revision = json.loads(payload)["judgment"]["revision"]
            if revision != log.succeeded[defect_id] and not log.failed.get(defect_id):
                log.revision_mismatches += 1
            log.measured_ok += measured
        else:
            log.failed[defect_id] += 1
            log.errors += 1
            log.measured_errors += measured
        if measured:
            log.latencies_ms.append((done - started) * 1000)
            log.last_done = max(log.last_done, done)


async def write_test(
    port: int, seeded: Seeded, *, seconds: float, server_pid: int
) -> tuple[dict[str, Any], list[WriterLog]]:
    connections = [RawHttp("127.0.0.1", port, token) for token in seeded.user_tokens]
    await asyncio.gather(*(c.connect() for c in connections))
    logs = [WriterLog(user_id=user_id) for user_id in seeded.user_ids]
    hot = seeded.defect_ids[:HOT_DEFECTS]
    start = time.perf_counter()
    measure_from, stop_at = start + WARMUP_S, start + WARMUP_S + seconds
    tasks = [
        asyncio.create_task(run_writer(i, c, log, hot, measure_from, stop_at))
        for i, (c, log) in enumerate(zip(connections, logs, strict=True))
    ]
    await asyncio.sleep(max(0.0, measure_from - time.perf_counter()))
    cpu_before = (time.process_time(), process_cpu_s(server_pid), system_cpu_ticks())
    wall_before = time.perf_counter()
    await asyncio.gather(*tasks)
    wall = time.perf_counter() - wall_before
    cpu_after = (time.process_time(), process_cpu_s(server_pid), system_cpu_ticks())
    await asyncio.gather(*(c.close() for c in connections))
    return summarize_writes(logs, measure_from, stop_at, wall, cpu_before, cpu_after), logs


def summarize_writes(
    logs: list[WriterLog],
    measure_from: float,
    stop_at: float,
    wall_s: float,
    cpu_before: tuple[float, float | None, tuple[int, int] | None],
    cpu_after: tuple[float, float | None, tuple[int, int] | None],
) -> dict[str, Any]:
    latencies = [ms for log in logs for ms in log.latencies_ms]
    ok = sum(log.measured_ok for log in logs)
    window = max(stop_at, *(log.last_done for log in logs)) - measure_from
    server_cpu = (
        None if cpu_before[1] is None or cpu_after[1] is None else cpu_after[1] - cpu_before[1]
    )
    statuses: Counter = Counter()
    for log in logs:
        statuses.update(log.statuses)
    return {
        "clients": len(logs),
        "window_s": round(window, 3),
        "requests": len(latencies),
        "writes": ok,
        "writes_per_s": round(ok / window, 1) if window > 0 else 0.0,
        **latency_summary(latencies),
        "errors": sum(log.errors for log in logs),
        "errors_in_window": sum(log.measured_errors for log in logs),
        "statuses": {str(k): v for k, v in sorted(statuses.items())},
        "revision_mismatches": sum(log.revision_mismatches for log in logs),
        "total_writes_including_warmup": sum(sum(log.succeeded.values()) for log in logs),
        "server_cpu_s": None if server_cpu is None else round(server_cpu, 3),
        "server_cpu_ms_per_write": (
            round(1000 * server_cpu / ok, 3) if server_cpu is not None and ok else None
        ),
        "loadgen_cpu_s": round(cpu_after[0] - cpu_before[0], 3),
        "machine_busy_percent": busy_percent(cpu_before[2], cpu_after[2]),
        "measured_wall_s": round(wall_s, 3),
    }


# --------------------------------------------------------------------------- integrity


def verify_judgments(url: str, logs: list[WriterLog]) -> dict[str, int]:
    """Compare what clients saw succeed with what the database holds.

    ``lost``: writes a client saw succeed that are missing (revision too low, a gap in the
    history). ``duplicated``: writes counted twice (revision too high, a repeated history
    entry, more than one current row for a pair). A write that failed on the client may or
    may not have landed, so it widens the accepted range instead of counting either way."""
    engine = make_engine(url)
    try:
        with engine.connect() as connection:
            current = {
                (defect, user): (rows, revision)
                for defect, user, rows, revision in connection.execute(
                    select(
                        Judgment.defect_id,
                        Judgment.user_id,
                        func.count(),
                        func.max(Judgment.revision),
                    ).group_by(Judgment.defect_id, Judgment.user_id)
                )
            }
            history: dict[tuple[int, int], list[int]] = defaultdict(list)
            for defect, user, revision in connection.execute(
                select(
                    JudgmentRevision.defect_id, JudgmentRevision.user_id, JudgmentRevision.revision
                )
            ):
                history[(defect, user)].append(revision)
            change_rows = connection.scalar(
                select(func.count()).select_from(Change).where(Change.entity == "judgment")
            )
    finally:
        engine.dispose()
    lost = duplicated = pairs = 0
    expected_pairs: set[tuple[int, int]] = set()
    for log in logs:
        for defect in set(log.succeeded) | set(log.failed):
            pair = (defect, log.user_id)
            expected_pairs.add(pair)
            pairs += 1
            low = log.succeeded.get(defect, 0)
            high = low + log.failed.get(defect, 0)
            rows, revision = current.get(pair, (0, 0))
            duplicated += max(0, rows - 1) + max(0, revision - high)
            lost += max(0, low - revision)
            seen = history.get(pair, [])
            duplicated += len(seen) - len(set(seen)) + len(set(seen) - set(range(1, revision + 1)))
            lost += len(set(range(1, revision + 1)) - set(seen))
    strangers = set(current) - expected_pairs
    duplicated += len(strangers)
    revisions_total = sum(len(h) for h in history.values())
    return {
        "pairs": pairs,
        "judgment_rows": sum(rows for rows, _ in current.values()),
        "revision_rows": revisions_total,
        "change_log_rows": int(change_rows or 0),
        "change_log_matches": int(change_rows or 0) == revisions_total,
        "lost": lost,
        "duplicated": duplicated,
    }


# --------------------------------------------------------------------------- page test


async def page_test(port: int, seeded: Seeded) -> dict[str, Any]:
    http = RawHttp("127.0.0.1", port, seeded.admin_token)
    rng = random.Random(SEED)
    ids = seeded.defect_ids
    latencies: list[float] = []
    wrong = errors = 0
    try:
        for i in range(PAGE_WARMUP_REQUESTS + PAGE_REQUESTS):
            offset = rng.randrange(0, len(ids) - PAGE_SIZE + 1)
            after = ids[offset - 1] if offset else 0
            path = (
                f"/api/v1/defects?inspection={seeded.inspection_id}&limit={PAGE_SIZE}"
                f"&cursor={encode_cursor(after)}"
            )
            started = time.perf_counter()
            try:
                status, payload = await asyncio.wait_for(
                    http.request("GET", path), REQUEST_TIMEOUT_S
                )
            except (OSError, TimeoutError, ValueError, IndexError, asyncio.IncompleteReadError):
                await http.close()
                status, payload = 0, b""
            elapsed_ms = (time.perf_counter() - started) * 1000
            if i < PAGE_WARMUP_REQUESTS:
                continue
            latencies.append(elapsed_ms)
            if status != 200:
                errors += 1
                continue
            got = [item["id"] for item in json.loads(payload)["items"]]
            wrong += got != ids[offset : offset + PAGE_SIZE]
    finally:
        await http.close()
    return {
        "requests": len(latencies),
        "page_size": PAGE_SIZE,
        "of_defects": len(ids),
        **latency_summary(latencies),
        "errors": errors,
        "wrong_pages": wrong,
    }


# --------------------------------------------------------------------------- one backend


def bench_backend(
    name: str,
    url: str,
    data_dir: Path,
    *,
    clients: int,
    seconds: float,
    defects: int,
    api_workers: int,
) -> dict[str, Any]:
    timings: dict[str, float] = {}
    started = time.perf_counter()
    _say(f"{name}: migrating")
    upgrade(url)
    timings["migrate_s"] = time.perf_counter() - started

    started = time.perf_counter()
    _say(f"{name}: seeding {clients} inspectors and {defects} defects")
    seeded = seed_database(url, clients=clients, defects=defects, rng=random.Random(SEED))
    timings["seed_s"] = time.perf_counter() - started

    started = time.perf_counter()
    _say(f"{name}: starting `vista serve`")
    with running_server(data_dir, url, api_workers) as server:
        timings["server_start_s"] = time.perf_counter() - started
        _say(
            f"{name}: {clients} clients writing judgments for {WARMUP_S:.0f} s warm-up "
            f"+ {seconds:g} s"
        )
        started = time.perf_counter()
        writes, logs = _run_async(
            write_test(server.port, seeded, seconds=seconds, server_pid=server.pid)
        )
        timings["write_test_s"] = time.perf_counter() - started
        _say(f"{name}: {writes['writes_per_s']} writes/s; paging {PAGE_REQUESTS} defect pages")
        started = time.perf_counter()
        pages = _run_async(page_test(server.port, seeded))
        timings["page_test_s"] = time.perf_counter() - started

    _say(f"{name}: verifying judgments in the database")
    started = time.perf_counter()
    integrity = verify_judgments(url, logs)
    timings["verify_s"] = time.perf_counter() - started
    result = {
        "database": name,
        "api_workers": api_workers,
        "writes": writes,
        "integrity": integrity,
        "page": pages,
        "durations": {k: round(v, 3) for k, v in timings.items()},
    }
    result["meets_targets"] = meets_targets(result)
    return result


def meets_targets(result: dict[str, Any]) -> dict[str, bool]:
    writes, page, integrity = result["writes"], result["page"], result["integrity"]
    return {
        "writes_per_s": writes["writes_per_s"] >= TARGETS["writes_per_s_min"],
        "write_p99": writes["p99_ms"] is not None
        and writes["p99_ms"] < TARGETS["write_p99_ms_max"],
        "page_p50": page["p50_ms"] is not None and page["p50_ms"] < TARGETS["page_p50_ms_max"],
        "no_errors": writes["errors"] == 0 and page["errors"] == 0 and page["wrong_pages"] == 0,
        "no_lost": integrity["lost"] == 0,
        "no_duplicated": integrity["duplicated"] == 0,
    }


# --------------------------------------------------------------------------- report


def _fmt(value: float | int | None, digits: int = 1) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def format_table(report: dict[str, Any]) -> str:
    header = (
        "database",
        "API procs",
        "writes/s",
        "p50 ms",
        "p99 ms",
        "errors",
        "lost",
        "dup",
        "page p50 ms",
        "page p99 ms",
        "targets",
    )
    rows = [header]
    for name, result in report["backends"].items():
        w, p, i = result["writes"], result["page"], result["integrity"]
        met = result["meets_targets"]
        rows.append(
            (
                name,
                str(result["api_workers"]),
                _fmt(w["writes_per_s"]),
                _fmt(w["p50_ms"]),
                _fmt(w["p99_ms"]),
                str(w["errors"] + p["errors"] + p["wrong_pages"]),
                str(i["lost"]),
                str(i["duplicated"]),
                _fmt(p["p50_ms"], 2),
                _fmt(p["p99_ms"], 2),
                "met"
                if all(met.values())
                else "missed: " + ",".join(k for k, v in met.items() if not v),
            )
        )
    rows.append(
        (
            "target",
            "",
            f">= {TARGETS['writes_per_s_min']:.0f}",
            "",
            f"< {TARGETS['write_p99_ms_max']:.0f}",
            "0",
            "0",
            "0",
            f"< {TARGETS['page_p50_ms_max']:.0f}",
            "",
            "",
        )
    )
    widths = [max(len(row[c]) for row in rows) for c in range(len(header))]
    lines = []
    for n, row in enumerate(rows):
        cells = [
            cell.ljust(widths[c]) if c in (0, len(row) - 1) else cell.rjust(widths[c])
            for c, cell in enumerate(row)
        ]
        lines.append("  ".join(cells).rstrip())
        if n == 0:
            lines.append("  ".join("-" * w for w in widths))
    p = report["parameters"]
    lines.append(
        f"{p['clients']} clients for {p['seconds']:g} s after {WARMUP_S:g} s warm-up; pages of "
        f"{PAGE_SIZE} out of {p['defects']} defects, {PAGE_REQUESTS} requests; "
        f"{report['machine']['cpu_count']} CPUs. Targets are for PostgreSQL."
    )
    return "\n".join(lines)


def machine_info() -> dict[str, Any]:
    return {
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def run_api_bench(
    *,
    out: Path,
    clients: int,
    seconds: float,
    defects: int,
    postgres_url: str | None,
    api_workers: int = 2,
) -> dict:
    """Run the bench on SQLite and, when ``postgres_url`` is given, PostgreSQL; print a table,
    write JSON to ``out`` and return the same dict."""
    if defects < PAGE_SIZE:
        raise ValueError(f"defects must be at least {PAGE_SIZE} to page through them")
    started_at = datetime.now(UTC)
    started = time.perf_counter()
    report: dict[str, Any] = {
        "benchmark": "api",
        "started_at": started_at.isoformat(),
        "parameters": {
            "clients": clients,
            "seconds": seconds,
            "warmup_s": WARMUP_S,
            "defects": defects,
            "postgres_api_workers": api_workers,
            "hot_defects": min(HOT_DEFECTS, defects),
            "page_size": PAGE_SIZE,
            "page_requests": PAGE_REQUESTS,
            "postgres": postgres_url is not None,
        },
        "machine": machine_info(),
        "targets": TARGETS,
        "backends": {},
    }
    with tempfile.TemporaryDirectory(prefix="vista-bench-sqlite-") as tmp:
        data_dir = Path(tmp)
        url = f"sqlite:///{(data_dir / 'vista.db').resolve()}"
        report["backends"]["sqlite"] = bench_backend(
            "sqlite",
            url,
            data_dir,
            clients=clients,
            seconds=seconds,
            defects=defects,
            api_workers=1,  # one writer at a time: SQLite is served by one process
        )
    if postgres_url:
        with (
            fresh_postgres_database(postgres_url) as url,
            tempfile.TemporaryDirectory(prefix="vista-bench-pg-") as tmp,
        ):
            report["backends"]["postgresql"] = bench_backend(
                "postgresql",
                url,
                Path(tmp),
                clients=clients,
                seconds=seconds,
                defects=defects,
                api_workers=api_workers,
            )
    else:
        _say("PostgreSQL skipped: pass --postgres-url or set VISTA_TEST_DATABASE_URL")
    report["duration_s"] = round(time.perf_counter() - started, 3)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(format_table(report))
    print(f"wrote {out}")
    return report
