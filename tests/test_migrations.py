from __future__ import annotations

from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import inspect

import supervisor.models  # noqa: F401 - registers every table
from supervisor.db import Base, make_engine
from supervisor.migrate import alembic_config, current_revision, head_revision, upgrade


def _diff(url: str) -> list:
    engine = make_engine(url)
    with engine.connect() as connection:
        diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    engine.dispose()
    return diff


def _tables(url: str) -> set[str]:
    engine = make_engine(url)
    names = set(inspect(engine).get_table_names())
    engine.dispose()
    return names


def test_migrations_build_exactly_the_models_and_go_back_down(database_url):
    # database_url is already at head (the fixtures build it with the migrations)
    assert current_revision(database_url) == head_revision()
    assert _diff(database_url) == []
    assert {t.name for t in Base.metadata.sorted_tables} <= _tables(database_url)
    command.downgrade(alembic_config(database_url), "base")
    assert _tables(database_url) <= {"alembic_version"}
    upgrade(database_url)
    assert _diff(database_url) == [] and current_revision(database_url) == head_revision()


def test_stored_jobs_take_the_service_verb_names_and_give_them_back(tmp_path):
    """0004 renames stored jobs' kinds (``measure`` → ``defects.measure`` …); the old names
    stay accepted as aliases, and a downgrade restores them."""
    import sqlite3

    url = f"sqlite:///{tmp_path / 'old.db'}"
    upgrade(url, "0003")
    old = ["calibrate", "stitch", "measure", "odometry", "track", "track.train", "depth.train"]
    now = "2026-11-20 10:00:00"
    with sqlite3.connect(tmp_path / "old.db") as db:
        db.execute(
            "INSERT INTO inspections (id, title, aircraft, serial, area, tolerances, markers, "
            "status, created_at, updated_at) VALUES (1, 'old', '', '', 'cabin', '{}', '[]', "
            "'planned', ?, ?)",
            (now, now),
        )
        db.execute(
            "INSERT INTO runs (id, inspection_id, name, created_at) VALUES (1, 1, '', ?)", (now,)
        )
        db.executemany(
            "INSERT INTO jobs (run_id, inspection_id, step, position, kind, queue, params, "
            "input_artifact_ids, status, progress, message, attempts, max_attempts, "
            "cancel_requested, created_at) VALUES (1, 1, ?, 0, ?, 'q', '{}', '[]', "
            "'succeeded', 1.0, '', 1, 3, 0, '2026-11-20 10:00:00')",
            [(name, name) for name in old],
        )

    def kinds() -> list[str]:
        with sqlite3.connect(tmp_path / "old.db") as db:
            return [k for (k,) in db.execute("SELECT kind FROM jobs ORDER BY id")]

    upgrade(url)
    renamed = ["stitching.calibrate", "stitching.stitch", "defects.measure", "odometry.run"]
    assert kinds() == [*renamed, "tracking.track", "tracking.train", "depth.train"]
    from supervisor.engine.registry import get_kind, load_kinds

    load_kinds()
    assert all(get_kind(name).name == new for name, new in zip(old, kinds(), strict=True))
    command.downgrade(alembic_config(url), "0003")
    assert kinds() == old
