"""A fresh database for a bench, seeded through the same write paths the API and the
engine use (users and tokens, an inspection, each finding as a job's is recorded), so a
bench meets the rows, lineage and change log a real installation has."""

from __future__ import annotations

import random
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta

from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session

from contract.context import NewDefect
from contract.vocabulary import DEFECT_TYPES, SEVERITIES
from supervisor.audit.service import Operator
from supervisor.db import Database
from supervisor.defects.service import record_defects
from supervisor.inspections import service as inspections
from supervisor.inspections.schemas import InspectionCreate
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


def bench_findings(count: int, rng: random.Random) -> list[NewDefect]:
    """Plausible, varied findings: every type and severity, spread over a fuselage section."""
    findings = []
    for i in range(count):
        kind = DEFECT_TYPES[i % len(DEFECT_TYPES)]
        tolerance = round(rng.uniform(0.2, 2.0), 3)
        value = round(tolerance * rng.uniform(1.05, 3.0), 3)
        samples = rng.randint(3, 400)
        location = (
            round(rng.uniform(0, 12_000), 2),
            round(rng.uniform(-2_000, 2_000), 2),
            round(rng.uniform(0, 2_500), 2),
        )
        extent = round(rng.uniform(0, 80), 2)
        severity = SEVERITIES[rng.randrange(len(SEVERITIES))]
        findings.append(
            NewDefect(
                type=kind,
                location_mm=location,
                normal=(0.0, 0.0, 1.0),
                value_mm=value,
                tolerance_mm=tolerance,
                extent_mm=extent,
                severity=severity,
                confidence=round(rng.uniform(0.5, 1.0), 3),
                measurements={"samples": samples, "method": "bench"},
            )
        )
    return findings


def new_inspection(
    session: Session, actor: Operator, *, title: str, area: str, **fields: str
) -> int:
    """An inspection under review, made as ``POST /inspections`` makes it (row, change
    log, audit)."""
    data = InspectionCreate(title=title, area=area, status="review", **fields)
    return inspections.create(session, data=data, actor=actor).id


def seed_database(url: str, *, clients: int, defects: int, rng: random.Random) -> Seeded:
    """Users with tokens, one inspection and its defects."""
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
            actor = Operator(admin.id, admin.username)
            inspection_id = new_inspection(
                session, actor, title="bench api", area="cargo", aircraft="A320", serial="MSN-BENCH"
            )
            defect_ids = record_defects(
                session, bench_findings(defects, rng), inspection_id=inspection_id, source="bench"
            )
    finally:
        db.dispose()
    return Seeded(admin_token, inspection_id, user_ids, user_tokens, defect_ids)
