"""The sign-in storm: does a flood of bad sign-ins slow down everyone else?

One client reads ``GET /api/v1/inspections`` with a valid token, first alone (idle), then
while ``attackers`` clients — each from its own loopback address, so per-address limits
do not stop them, each with new usernames, so per-account limits do not either — post
wrong passwords as fast as the server answers. The reader's p50/p99 in both phases, the
ratio, and what the attackers got (401 checked, 429 turned away) are reported.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections import Counter
from typing import Any

from benches.http import RawHttp
from benches.stats import latency_summary

READ_PATH = "/api/v1/inspections?limit=20"
TIMEOUT_S = 30.0
TARGET_P99_RATIO = 2.0


async def _read_for(reader: RawHttp, seconds: float) -> list[float]:
    latencies: list[float] = []
    stop_at = time.perf_counter() + seconds
    while time.perf_counter() < stop_at:
        started = time.perf_counter()
        status, _ = await reader.try_request("GET", READ_PATH, timeout_s=TIMEOUT_S)
        if status == 200:
            latencies.append(1000 * (time.perf_counter() - started))
        await asyncio.sleep(0.01)  # a user's pace, not a second flood
    return latencies


async def _attack(index: int, port: int, stop: asyncio.Event, statuses: Counter) -> None:
    client = RawHttp("127.0.0.1", port, None, local_address=f"127.0.0.{index + 2}")
    attempt = 0
    while not stop.is_set():
        attempt += 1
        body = json.dumps({"username": f"storm-{index}-{attempt}", "password": "wrong"}).encode()
        status, _ = await client.try_request(
            "POST", "/api/v1/auth/token", body, timeout_s=TIMEOUT_S
        )
        statuses[status] += 1
        if status == 429:
            await asyncio.sleep(0.05)  # turned away cheaply: come straight back
    await client.close()


async def sign_in_storm(
    port: int, token: str, *, attackers: int = 16, seconds: float = 8.0
) -> dict[str, Any]:
    reader = RawHttp("127.0.0.1", port, token)
    await reader.connect()
    await _read_for(reader, 1.0)  # warm-up
    idle = latency_summary(await _read_for(reader, seconds))
    stop, statuses = asyncio.Event(), Counter()
    attacks = [asyncio.create_task(_attack(i, port, stop, statuses)) for i in range(attackers)]
    await asyncio.sleep(0.5)  # the storm is on
    storm = latency_summary(await _read_for(reader, seconds))
    stop.set()
    await asyncio.gather(*attacks)
    await reader.close()
    ratio = (
        round(storm["p99_ms"] / idle["p99_ms"], 2)
        if storm["p99_ms"] is not None and idle["p99_ms"]
        else None
    )
    return {
        "attackers": attackers,
        "seconds": seconds,
        "idle": idle,
        "storm": storm,
        "p99_ratio": ratio,
        "meets_target": ratio is not None and ratio <= TARGET_P99_RATIO,
        "sign_in_statuses": {str(k): v for k, v in sorted(statuses.items())},
    }
