"""The API bench's load: concurrent judgment writers, the integrity check of what they
wrote (straight from the database), and the defect-page reader."""

from __future__ import annotations

import asyncio
import json
import os
import random
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import func, select

from benches.http import RawHttp
from benches.seeding import Seeded
from benches.stats import busy_percent, latency_summary, process_cpu_s, system_cpu_ticks
from supervisor.db import make_engine
from supervisor.models import Change, Judgment, JudgmentRevision
from supervisor.pagination import encode_cursor

WARMUP_S = 1.0
HOT_DEFECTS = 500
PAGE_SIZE = 100
PAGE_REQUESTS = 200
PAGE_WARMUP_REQUESTS = 10
VERDICT_CYCLE = ("confirmed", "rejected", "uncertain")
REQUEST_TIMEOUT_S = 30.0
SEED = 20240601


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
        status, payload = await http.try_request(
            "PUT",
            f"/api/v1/defects/{defect_id}/judgments/me",
            judgment_body(index, counter),
            timeout_s=REQUEST_TIMEOUT_S,
        )
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
        "loadgen_machine_percent": round(
            100 * (cpu_after[0] - cpu_before[0]) / (wall_s * (os.cpu_count() or 1)), 1
        ),
        "machine_busy_percent": busy_percent(cpu_before[2], cpu_after[2]),
        "measured_wall_s": round(wall_s, 3),
    }


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
            status, payload = await http.try_request("GET", path, timeout_s=REQUEST_TIMEOUT_S)
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
