"""`vista bench api`: the integrity check catches what it should, and a short run works."""

from __future__ import annotations

import json
import os
import random
from pathlib import Path

import pytest
from sqlalchemy import insert

from benches.api import cpu_plan, format_table, meets_targets, run_api_bench
from benches.load import PAGE_REQUESTS, WriterLog, verify_judgments
from benches.seeding import seed_database
from benches.stats import percentile
from supervisor.db import make_engine
from supervisor.models import Judgment, JudgmentRevision
from supervisor.models._types import utcnow
from tests.conftest import NO_POSTGRES, PG_URL


def test_percentile_is_nearest_rank() -> None:
    values = [float(v) for v in range(1, 101)]
    assert percentile(values, 50) == 50.0
    assert percentile(values, 99) == 99.0
    assert percentile(values, 100) == 100.0
    assert percentile([7.0], 99) == 7.0
    assert percentile([], 50) is None


def _judgment(defect_id: int, user_id: int, revision: int, revisions: list[int]) -> list:
    now = utcnow()
    common = {"defect_id": defect_id, "user_id": user_id, "verdict": "confirmed", "comment": ""}
    return [
        insert(Judgment).values(**common, revision=revision, updated_at=now),
        *(insert(JudgmentRevision).values(**common, revision=r, created_at=now) for r in revisions),
    ]


def test_verify_counts_lost_and_duplicated_writes(sqlite_url: str) -> None:
    seeded = seed_database(sqlite_url, clients=2, defects=200, rng=random.Random(1))
    d1, d2, d3, d4 = seeded.defect_ids[:4]
    u1, u2 = seeded.user_ids
    engine = make_engine(sqlite_url)
    with engine.begin() as connection:
        for statement in [
            *_judgment(d1, u1, 2, [1, 2]),  # exact: 2 writes seen, 2 stored
            *_judgment(d2, u1, 1, [1]),  # lost: 2 writes seen, 1 stored
            *_judgment(d3, u2, 3, [1, 2, 3]),  # duplicated: 2 writes seen, 3 stored
            *_judgment(d4, u2, 2, [2]),  # lost: history has a gap
        ]:
            connection.execute(statement)
    engine.dispose()
    first, second = WriterLog(user_id=u1), WriterLog(user_id=u2)
    first.succeeded.update({d1: 2, d2: 2})
    second.succeeded.update({d3: 2, d4: 2})

    result = verify_judgments(sqlite_url, [first, second])

    assert result["pairs"] == 4
    assert result["lost"] == 1 + 1
    assert result["duplicated"] == 1


def test_verify_accepts_a_failed_write_either_way(sqlite_url: str) -> None:
    seeded = seed_database(sqlite_url, clients=1, defects=200, rng=random.Random(1))
    defect, user = seeded.defect_ids[0], seeded.user_ids[0]
    engine = make_engine(sqlite_url)
    with engine.begin() as connection:
        for statement in _judgment(defect, user, 2, [1, 2]):
            connection.execute(statement)
    engine.dispose()
    log = WriterLog(user_id=user)
    log.succeeded[defect] = 1
    log.failed[defect] = 1  # the client got an error but the write landed

    result = verify_judgments(sqlite_url, [log])

    assert (result["lost"], result["duplicated"]) == (0, 0)


@pytest.mark.parametrize("with_postgres", [False, True], ids=["sqlite", "postgres"])
def test_short_run_writes_json_and_loses_nothing(tmp_path: Path, with_postgres: bool) -> None:
    if with_postgres and not PG_URL:
        pytest.skip(NO_POSTGRES)
    out = tmp_path / "deep" / "api.json"

    report = run_api_bench(
        out=out,
        clients=4,
        seconds=1,
        defects=300,
        postgres_url=PG_URL if with_postgres else None,
        api_workers=(2,),
        sqlite_normal=False,
        storm_s=0.5,
    )

    assert json.loads(out.read_text()) == json.loads(json.dumps(report))
    assert set(report["backends"]) == ({"sqlite", "postgresql-2"} if with_postgres else {"sqlite"})
    for result in report["backends"].values():
        writes, integrity, page = result["writes"], result["integrity"], result["page"]
        assert writes["writes"] > 0 and writes["errors"] == 0
        assert writes["revision_mismatches"] == 0
        assert integrity["lost"] == 0 and integrity["duplicated"] == 0
        assert integrity["change_log_matches"]
        assert integrity["revision_rows"] == writes["total_writes_including_warmup"]
        assert page["requests"] == PAGE_REQUESTS
        assert page["errors"] == 0 and page["wrong_pages"] == 0
        storm = result["sign_in_storm"]
        assert storm["idle"]["p99_ms"] is not None and storm["storm"]["p99_ms"] is not None
        assert sum(storm["sign_in_statuses"].values()) > 0
        assert set(storm["sign_in_statuses"]) <= {"401", "429"}
        assert 0 < writes["loadgen_machine_percent"] <= 100  # the generator's share, stated
        assert result["cpus"] == cpu_plan(os.sched_getaffinity(0))
    assert "writes/s" in format_table(report) and "gen CPU %" in format_table(report)
    if with_postgres:  # the fault row: the database away a third of the window
        fault = report["fault"]
        assert (fault["server_errors"], fault["resets"], fault["lost"]) == (0, 0, 0), fault
        assert fault["writes_per_s"] > 0 and fault["meets_targets"]
    else:
        assert report["fault"] is None


def test_sqlite_is_held_to_its_own_targets_and_postgresql_to_the_stricter_ones() -> None:
    """Issue 35: SQLite (one process, one file) p99 < 150 ms at ≥ 200 writes/s; PostgreSQL
    p99 < 100 ms at ≥ 300 writes/s."""

    def run(database: str, writes_per_s: float, p99_ms: float) -> dict:
        return {
            "database": database,
            "writes": {"writes_per_s": writes_per_s, "p99_ms": p99_ms, "errors": 0},
            "page": {"p50_ms": 10.0, "errors": 0, "wrong_pages": 0},
            "integrity": {"lost": 0, "duplicated": 0},
            "sign_in_storm": {"meets_target": True},
        }

    for database in ("sqlite", "sqlite-normal"):
        assert all(meets_targets(run(database, 250.0, 120.0)).values())
        met = meets_targets(run(database, 190.0, 150.0))
        assert not met["writes_per_s"] and not met["write_p99"]
    met = meets_targets(run("postgresql-2", 250.0, 120.0))
    assert not met["writes_per_s"] and not met["write_p99"]
    assert all(meets_targets(run("postgresql-1", 300.0, 99.0)).values())


def test_the_generator_gets_a_cpu_of_its_own_only_on_a_machine_that_can_spare_one() -> None:
    assert cpu_plan({0, 1})["pinned"] is False and "2 CPUs" in cpu_plan({0, 1})["why"]
    assert cpu_plan({0, 1, 2, 3}) == {
        "pinned": True,
        "generator_cpus": [3],
        "server_cpus": [0, 1, 2],
    }


def test_a_pinned_server_and_its_api_processes_run_on_their_cpus(tmp_path: Path) -> None:
    from benches.server import running_server
    from supervisor.migrate import upgrade

    url = f"sqlite:///{tmp_path / 'vista.db'}"
    upgrade(url)
    with running_server(tmp_path, url, 1, cores={0}) as server:
        assert os.sched_getaffinity(server.pid) == {0}
