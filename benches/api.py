"""``vista api bench``: the API under load, against a real ``vista serve`` process.

For SQLite (always) and PostgreSQL (when a server URL is given), on a fresh database:

* **judgment writes** — ``clients`` concurrent reviewers each PUT their own judgment on
  defects they share with the others, every PUT changing something; writes/s and the
  p50/p99 latency after a warm-up;
* **integrity** — afterwards, straight from the database: one ``judgments`` row per
  (user, defect), its ``revision`` equal to the writes that client saw succeed, and the
  history exactly revisions 1..N (nothing lost, nothing duplicated);
* **defect pages** — 100-item pages out of ``defects`` at random cursors, one client;
* **sign-in storm** — an authenticated reader's p99 alone and under 16 clients posting
  wrong passwords from 16 addresses (``bench.signin``): the target is at most 2× idle.

SQLite runs twice: with ``synchronous=FULL`` (the default: no acknowledged commit lost on
power loss) and ``NORMAL``, so the cost of durability is measured in the same run.

The load generator is a tiny keep-alive HTTP/1.1 client on one event loop, so it takes as
little of the machine's CPU from the server as it can. On a machine of 4 or more CPUs it
runs on a CPU of its own and the server on the others (``cpu_plan``); on fewer the two share
them, and the generator's own CPU time (its share of the machine) is reported beside the
figures it may have cost.
"""

from __future__ import annotations

import os
import random
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from benches.http import run_async
from benches.load import (
    HOT_DEFECTS,
    PAGE_REQUESTS,
    PAGE_SIZE,
    SEED,
    WARMUP_S,
    page_test,
    verify_judgments,
    write_test,
)
from benches.seeding import fresh_postgres_database, seed_database
from benches.server import running_server
from benches.signin import sign_in_storm
from contract.bench import say, write_document
from supervisor.migrate import upgrade

TARGETS = {
    "writes_per_s_min": 300.0,
    "write_p99_ms_max": 100.0,
    "page_p50_ms_max": 20.0,
    "lost": 0,
    "duplicated": 0,
}
"""PostgreSQL's, whatever the number of API processes."""
SQLITE_TARGETS = {**TARGETS, "writes_per_s_min": 200.0, "write_p99_ms_max": 150.0}
"""SQLite's (one process writing one file, issue 35): p99 < 150 ms at ≥ 200 writes/s."""


def targets_for(database: str) -> dict[str, float]:
    """The targets of a run named ``database`` (``sqlite…`` or ``postgresql-N``)."""
    return SQLITE_TARGETS if database.startswith("sqlite") else TARGETS


def _say(message: str) -> None:
    say(f"[bench api] {message}")


MIN_CPUS_TO_PIN = 4
"""Below this the server would lose too much to a CPU of the generator's own."""


def cpu_plan(cpus: set[int]) -> dict[str, Any]:
    """Where the load generator and the server run: apart when the machine has
    ``MIN_CPUS_TO_PIN`` CPUs or more (the generator on the last), else together."""
    if len(cpus) < MIN_CPUS_TO_PIN:
        return {
            "pinned": False,
            "why": f"{len(cpus)} CPUs: the generator shares them with the server; its CPU "
            "share is stated instead",
        }
    generator = max(cpus)
    return {
        "pinned": True,
        "generator_cpus": [generator],
        "server_cpus": sorted(cpus - {generator}),
    }


@contextmanager
def _generator_on(plan: dict[str, Any]) -> Iterator[None]:
    """This process (the load generator) on its CPUs for the while, when the plan pins."""
    if not plan["pinned"]:
        yield
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, set(plan["generator_cpus"]))
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def bench_backend(
    name: str,
    url: str,
    data_dir: Path,
    *,
    clients: int,
    seconds: float,
    defects: int,
    api_workers: int,
    storm_s: float,
    extra_env: dict[str, str] | None = None,
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
    plan = cpu_plan(os.sched_getaffinity(0))
    _say(f"{name}: starting `vista serve`")
    server_cpus = set(plan["server_cpus"]) if plan["pinned"] else None
    with (
        running_server(data_dir, url, api_workers, extra_env, server_cpus) as server,
        _generator_on(plan),
    ):
        timings["server_start_s"] = time.perf_counter() - started
        _say(
            f"{name}: {clients} clients writing judgments for {WARMUP_S:.0f} s warm-up "
            f"+ {seconds:g} s"
        )
        started = time.perf_counter()
        writes, logs = run_async(
            write_test(server.port, seeded, seconds=seconds, server_pid=server.pid)
        )
        timings["write_test_s"] = time.perf_counter() - started
        _say(f"{name}: {writes['writes_per_s']} writes/s; paging {PAGE_REQUESTS} defect pages")
        started = time.perf_counter()
        pages = run_async(page_test(server.port, seeded))
        timings["page_test_s"] = time.perf_counter() - started
        _say(f"{name}: sign-in storm (16 clients posting wrong passwords)")
        started = time.perf_counter()
        storm = run_async(sign_in_storm(server.port, seeded.admin_token, seconds=storm_s))
        timings["sign_in_storm_s"] = time.perf_counter() - started

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
        "sign_in_storm": storm,
        "settings": extra_env or {},
        "cpus": plan,
        "durations": {k: round(v, 3) for k, v in timings.items()},
    }
    result["meets_targets"] = meets_targets(result)
    return result


OUTAGE_S = 5.0
"""How long the fault row's database is away (a restart of PostgreSQL takes a few s)."""


def bench_fault(
    postgres_url: str, *, clients: int, seconds: float, defects: int, outage_s: float = OUTAGE_S
) -> dict[str, Any]:
    """The write test against PostgreSQL through a proxy cut for ``outage_s`` a third of
    the way into the measured window (every connection dropped, new ones refused: what the
    API sees while the database restarts), then restored: writes/s and p99 over the whole
    window, every answer's status — 5xx other than 503 (target 0), 503s with Retry-After
    counted apart, connections reset — and whether an acknowledged write was lost."""
    from urllib.parse import urlsplit

    from sqlalchemy.engine import make_url

    from benches.faultproxy import FaultProxy

    with (
        fresh_postgres_database(postgres_url) as url,
        tempfile.TemporaryDirectory(prefix="vista-bench-fault-") as tmp,
    ):
        upgrade(url)
        seeded = seed_database(url, clients=clients, defects=defects, rng=random.Random(SEED))
        target = urlsplit(make_url(url).render_as_string(hide_password=False))
        proxy = FaultProxy((target.hostname or "127.0.0.1", target.port or 5432))
        proxied = make_url(url).set(host="127.0.0.1", port=proxy.port)
        try:
            with running_server(Path(tmp), proxied.render_as_string(False), 1) as server:
                cut_at = WARMUP_S + seconds / 3
                timers = [
                    threading.Timer(cut_at, proxy.cut),
                    threading.Timer(cut_at + outage_s, proxy.restore),
                ]
                for timer in timers:
                    timer.start()
                _say(f"fault: {clients} clients writing; the database away {outage_s:g} s")
                writes, logs = run_async(
                    write_test(server.port, seeded, seconds=seconds, server_pid=server.pid)
                )
                for timer in timers:
                    timer.join()
        finally:
            proxy.close()
        integrity = verify_judgments(url, logs)
    statuses = {int(k): v for k, v in writes["statuses"].items()}
    result = {
        "outage_s": outage_s,
        "writes_per_s": writes["writes_per_s"],
        "p99_ms": writes["p99_ms"],
        "server_errors": sum(v for k, v in statuses.items() if k >= 500 and k != 503),
        "unavailable_503": statuses.get(503, 0),
        "resets": statuses.get(0, 0),
        "lost": integrity["lost"],
        "duplicated": integrity["duplicated"],
        "statuses": writes["statuses"],
    }
    result["meets_targets"] = (
        result["server_errors"] == 0 and result["resets"] == 0 and (result["lost"] == 0)
    )
    return result


def format_fault(fault: dict[str, Any]) -> str:
    return (
        f"fault (PostgreSQL away {fault['outage_s']:g} s mid-write): {fault['writes_per_s']} "
        f"writes/s, p99 {_fmt(fault['p99_ms'])} ms, 5xx {fault['server_errors']} (target 0), "
        f"503 {fault['unavailable_503']}, resets {fault['resets']}, lost {fault['lost']}: "
        + ("met" if fault["meets_targets"] else "missed")
    )


def meets_targets(result: dict[str, Any]) -> dict[str, bool]:
    writes, page, integrity = result["writes"], result["page"], result["integrity"]
    targets = targets_for(result["database"])
    return {
        "writes_per_s": writes["writes_per_s"] >= targets["writes_per_s_min"],
        "write_p99": writes["p99_ms"] is not None
        and writes["p99_ms"] < targets["write_p99_ms_max"],
        "page_p50": page["p50_ms"] is not None and page["p50_ms"] < targets["page_p50_ms_max"],
        "no_errors": writes["errors"] == 0 and page["errors"] == 0 and page["wrong_pages"] == 0,
        "no_lost": integrity["lost"] == 0,
        "no_duplicated": integrity["duplicated"] == 0,
        "sign_in_storm": result["sign_in_storm"]["meets_target"],
    }


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
        "idle p99",
        "storm p99",
        "gen CPU %",
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
                _fmt(result["sign_in_storm"]["idle"]["p99_ms"]),
                _fmt(result["sign_in_storm"]["storm"]["p99_ms"]),
                _fmt(w["loadgen_machine_percent"])
                + (" (own CPU)" if result["cpus"]["pinned"] else " (shared)"),
                "met"
                if all(met.values())
                else "missed: " + ",".join(k for k, v in met.items() if not v),
            )
        )
    for name, targets in (("target", TARGETS), ("target sqlite", SQLITE_TARGETS)):
        rows.append(
            (
                name,
                "",
                f">= {targets['writes_per_s_min']:.0f}",
                "",
                f"< {targets['write_p99_ms_max']:.0f}",
                "0",
                "0",
                "0",
                f"< {targets['page_p50_ms_max']:.0f}",
                "",
                "",
                "<= 2x idle",
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
        f"{report['machine']['cpus']} CPUs. `target` is PostgreSQL's (postgresql-N: served by N "
        "API processes), `target sqlite` SQLite's (one process, one file). sqlite-normal: "
        "synchronous=NORMAL (may lose the last commits on power loss; the default is FULL). "
        "gen CPU %: the load generator's share of the machine while writing — on its own CPU "
        "when the machine has 4 or more, else taken from the server's."
    )
    return "\n".join(lines)


def run_api_bench(
    *,
    out: Path,
    clients: int,
    seconds: float,
    defects: int,
    postgres_url: str | None,
    api_workers: tuple[int, ...] = (1, 2),
    sqlite_normal: bool = True,
    storm_s: float = 8.0,
) -> dict:
    """Run the bench on SQLite and, when ``postgres_url`` is given, PostgreSQL served by each
    of ``api_workers`` API process counts (a fresh database each); print a table, write
    JSON to ``out`` and return the same dict."""
    if defects < PAGE_SIZE:
        raise ValueError(f"defects must be at least {PAGE_SIZE} to page through them")
    started = time.perf_counter()
    parameters = {
        "clients": clients,
        "seconds": seconds,
        "warmup_s": WARMUP_S,
        "defects": defects,
        "postgres_api_workers": list(api_workers),
        "hot_defects": min(HOT_DEFECTS, defects),
        "page_size": PAGE_SIZE,
        "page_requests": PAGE_REQUESTS,
        "postgres": postgres_url is not None,
    }
    backends: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="vista-bench-sqlite-") as tmp:
        data_dir = Path(tmp)
        url = f"sqlite:///{(data_dir / 'vista.db').resolve()}"
        backends["sqlite"] = bench_backend(
            "sqlite",
            url,
            data_dir,
            clients=clients,
            seconds=seconds,
            defects=defects,
            api_workers=1,  # one writer at a time: SQLite is served by one process
            storm_s=storm_s,
        )
    if sqlite_normal:
        with tempfile.TemporaryDirectory(prefix="vista-bench-sqlite-normal-") as tmp:
            data_dir = Path(tmp)
            backends["sqlite-normal"] = bench_backend(
                "sqlite-normal",
                f"sqlite:///{(data_dir / 'vista.db').resolve()}",
                data_dir,
                clients=clients,
                seconds=seconds,
                defects=defects,
                api_workers=1,
                storm_s=storm_s,
                extra_env={"VISTA_SQLITE_SYNCHRONOUS": "NORMAL"},
            )
    for processes in api_workers if postgres_url else ():
        name = f"postgresql-{processes}"
        with (
            fresh_postgres_database(postgres_url) as url,
            tempfile.TemporaryDirectory(prefix="vista-bench-pg-") as tmp,
        ):
            backends[name] = bench_backend(
                name,
                url,
                Path(tmp),
                clients=clients,
                seconds=seconds,
                defects=defects,
                api_workers=processes,
                storm_s=storm_s,
            )
    fault = None
    if postgres_url:
        fault = bench_fault(
            postgres_url,
            clients=clients,
            seconds=seconds,
            defects=defects,
            outage_s=min(OUTAGE_S, seconds / 3),
        )
    else:
        _say("PostgreSQL skipped: pass --postgres-url or set VISTA_TEST_DATABASE_URL")
    report = write_document(
        out,
        bench="api",
        targets={"postgresql": TARGETS, "sqlite": SQLITE_TARGETS},
        parameters=parameters,
        backends=backends,
        fault=fault,
        duration_s=round(time.perf_counter() - started, 3),
    )
    print(format_table(report))
    if fault is not None:
        print(format_fault(fault))
    print(f"wrote {out}")
    return report
