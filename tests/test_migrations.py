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
