"""Percentiles of latencies and the CPU time of processes and of the machine (Linux /proc)."""

from __future__ import annotations

import math
import os
from contextlib import suppress
from pathlib import Path


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
