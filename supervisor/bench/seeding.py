"""A fresh database for a bench, seeded straight through the models: users with tokens,
an inspection and its defects."""

from __future__ import annotations

import random
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import create_engine, insert, select, text
from sqlalchemy.engine import make_url

from contract.vocabulary import DEFECT_TYPES, SEVERITIES
from supervisor.db import Database
from supervisor.models import Defect, Inspection
from supervisor.users.service import create_token, create_user

BENCH_TOKEN_TTL = timedelta(days=1)


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
            admin = create_user(session, username="bench-admin", role="admin", password_hash=None)
            admin_token = create_token(
                session, user=admin, name="bench", kind="cli", ttl=BENCH_TOKEN_TTL
            )
            user_ids, user_tokens = [], []
            for index in range(clients):
                user = create_user(
                    session,
                    username=f"bench-inspector-{index:03d}",
                    role="inspector",
                    password_hash=None,
                )
                user_tokens.append(
                    create_token(session, user=user, name="bench", kind="cli", ttl=BENCH_TOKEN_TTL)
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
