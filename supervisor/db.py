"""Database engine and sessions, the same code on SQLite and PostgreSQL.

SQLite needs two things to be a fair multi-writer store: WAL with a busy timeout, and
write transactions that take the write lock when they begin (``BEGIN IMMEDIATE``) so two
writers never deadlock upgrading a read lock. Read sessions begin a plain deferred
transaction so they never wait for a writer.

SQLite's ``synchronous`` level is FULL unless asked otherwise: in WAL mode NORMAL syncs
the log only at checkpoints, so a power loss can undo commits the API already answered
(an upload acknowledged, its row gone); FULL syncs the log at every commit.
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, Literal, get_args

import orjson
from sqlalchemy import MetaData, create_engine, event
from sqlalchemy.engine import Connection, Engine
from sqlalchemy.orm import DeclarativeBase, Session, sessionmaker

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


SqliteSynchronous = Literal["FULL", "NORMAL"]


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)


class FairLock:
    """A lock granted in the order it was asked for: the holder hands it straight to the
    longest waiter. ``threading.Lock`` wakes an arbitrary waiter, and a thread that just
    released it often takes it again first: under 32 writers some waited three times the
    median for their turn."""

    def __init__(self) -> None:
        self._guard = threading.Lock()
        self._waiters: deque[threading.Lock] = deque()
        self._held = False

    def acquire(self) -> None:
        with self._guard:
            if not self._held:
                self._held = True
                return
            turn = threading.Lock()
            turn.acquire()
            self._waiters.append(turn)
        turn.acquire()  # released by the holder's release(): the lock is now ours

    def release(self) -> None:
        with self._guard:
            if self._waiters:
                self._waiters.popleft().release()
            else:
                self._held = False


def _configure_sqlite(engine: Engine, synchronous: SqliteSynchronous) -> None:
    # SQLite's busy handler polls with growing sleeps, so waiting writers of one process
    # overtake each other unfairly (p99 in seconds under load); a lock queues them.
    writer = FairLock()

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: sqlite3.Connection, _record: object) -> None:
        dbapi_connection.isolation_level = None  # SQLAlchemy emits BEGIN itself below
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute(f"PRAGMA synchronous={synchronous}")
        cursor.execute("PRAGMA busy_timeout=30000")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.close()

    @event.listens_for(engine, "begin")
    def _on_begin(connection: Connection) -> None:
        write = connection.get_execution_options().get("vista_write", False)
        if write:
            writer.acquire()
            connection.info["vista_writer"] = True
        try:
            connection.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")
        except BaseException:
            _release(connection)
            raise

    def _release(connection: Connection) -> None:
        if connection.info.pop("vista_writer", False):
            writer.release()

    event.listen(engine, "commit", _release)
    event.listen(engine, "rollback", _release)


def json_loads(text: str | bytes) -> Any:
    """JSON columns read with orjson (several times faster than the standard library on a
    sync's 30 000 small documents); text orjson refuses (a NaN literal that json.dumps once
    wrote) falls back to the standard library."""
    try:
        return orjson.loads(text)
    except orjson.JSONDecodeError:
        return json.loads(text)


def make_engine(url: str, *, sqlite_synchronous: SqliteSynchronous = "FULL") -> Engine:
    """An engine for ``url``; ``sqlite_synchronous``: SQLite's durability (see above)."""
    if url.startswith("sqlite"):
        if sqlite_synchronous not in get_args(SqliteSynchronous):  # it goes into a PRAGMA
            raise ValueError(
                f"sqlite_synchronous must be FULL or NORMAL, not {sqlite_synchronous!r}"
            )
        engine = create_engine(
            url,
            connect_args={"check_same_thread": False, "timeout": 30},
            json_deserializer=json_loads,
        )
        _configure_sqlite(engine, sqlite_synchronous)
        return engine
    # No ping per checkout (it doubles the round trips of a short request); a connection
    # the server dropped is invalidated on first use and the pool reconnects.
    return create_engine(
        url, pool_size=20, max_overflow=20, pool_recycle=1800, json_deserializer=json_loads
    )


class Database:
    """An engine with a read and a write session factory."""

    def __init__(self, url: str, *, sqlite_synchronous: SqliteSynchronous = "FULL") -> None:
        self.url = url
        self.engine = make_engine(url, sqlite_synchronous=sqlite_synchronous)
        self.is_sqlite = self.engine.dialect.name == "sqlite"
        self._read = sessionmaker(self.engine, expire_on_commit=False)
        self._write = sessionmaker(
            self.engine.execution_options(vista_write=True), expire_on_commit=False
        )

    @contextmanager
    def read(self) -> Iterator[Session]:
        with self._read() as session:
            yield session

    @contextmanager
    def write(self) -> Iterator[Session]:
        """A session whose transaction commits on success and rolls back on error."""
        with self._write() as session, session.begin():
            yield session

    @contextmanager
    def autocommit(self) -> Iterator[Connection]:
        """A connection where each statement commits by itself (no BEGIN/COMMIT trips)."""
        with self.engine.connect() as connection:
            yield connection.execution_options(isolation_level="AUTOCOMMIT")

    def session(self, *, write: bool) -> Session:
        """A session the caller manages (commits itself); used per API request."""
        return (self._write if write else self._read)()

    def dispose(self) -> None:
        self.engine.dispose()


_AFTER_COMMIT = "after_commit"


def after_commit(session: Session, action: Callable[[], None]) -> None:
    """Run ``action`` once ``session``'s transaction has committed (never if it rolls
    back): sending jobs to the queue, deleting stored files of removed rows."""
    session.info.setdefault(_AFTER_COMMIT, []).append(action)


def commit(session: Session) -> None:
    """Commit ``session`` and run what was asked to follow the commit."""
    session.commit()
    for action in session.info.pop(_AFTER_COMMIT, []):
        action()
