"""Applying and checking the Alembic migrations (the only way the schema changes)."""

from __future__ import annotations

from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import inspect

from supervisor.db import make_engine

MIGRATIONS_DIR = Path(__file__).resolve().parent.parent / "migrations"


def alembic_config(url: str) -> Config:
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    config.attributes["url"] = url
    return config


def upgrade(url: str, revision: str = "head") -> None:
    command.upgrade(alembic_config(url), revision)


def head_revision() -> str:
    return ScriptDirectory.from_config(alembic_config("")).get_current_head() or ""


def current_revision(url: str) -> str | None:
    engine = make_engine(url)
    try:
        with engine.connect() as connection:
            return MigrationContext.configure(connection).get_current_revision()
    finally:
        engine.dispose()


class SchemaOutOfDate(RuntimeError):
    pass


def check_schema(url: str) -> str | None:
    """Raises ``SchemaOutOfDate`` unless the database is at this vista's migration. A new
    embedded SQLite database (no tables yet) is created and migrated here instead; the
    sentence saying so is returned."""
    current, head = current_revision(url), head_revision()
    if current is None and url.startswith("sqlite") and not _has_tables(url):
        upgrade(url, head)
        return f"created the database {url.removeprefix('sqlite:///')} (migration {head})"
    if current != head:
        raise SchemaOutOfDate(
            f"the database is at migration {current or 'none'} but this vista needs {head}: "
            "run `vista migrate` first"
        )
    return None


def _has_tables(url: str) -> bool:
    engine = make_engine(url)
    try:
        return bool(inspect(engine).get_table_names())
    finally:
        engine.dispose()
