"""``vista demo``: a simulated cabin sidewall inspected end to end through the real API.

It simulates a curved assembly of lining panels with seams out of tolerance and surface
defects, then — as a client would — creates an inspection with tolerances, uploads the
calibration pairs and the scans, and starts one run calibrate → stitch → measure. The
jobs run on this installation's engine (embedded, or the workers of a broker), and the
findings land in the inspection's defect list, ready for reviewers.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from pathlib import Path

from supervisor.audit.service import COMMAND_LINE
from supervisor.engine.registry import declared_hooks
from supervisor.settings import Settings, secure_data_dir

DEMO_USER = "demo"
TOLERANCES = {
    "gap_mm": {"min": 0.5, "max": 3.0},
    "step_mm": {"max": 0.8},
    "parallelism_mm": {"max": 0.5},
    "mismatch_mm": {"max": 1.0},
    "surface": {"dent_depth_mm": 0.3, "scratch_depth_mm": 0.1, "color_delta_e": 4.0},
}


PART_T_CABIN_MARKER = [
    [1.0, 0.0, 0.0, -80.0],
    [0.0, 1.0, 0.0, 50.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
]
"""The cabin's image marker: printed beside the sidewall, 80 mm before its first panel."""


def _cabin_marker(truth_path: Path) -> dict:
    import json

    import numpy as np

    base_T_part = np.array(json.loads(truth_path.read_text())["base_T_part"])
    base_T_marker = base_T_part @ np.array(PART_T_CABIN_MARKER)
    return {
        "name": "cabin-sidewall",
        "area": "cabin",
        "base_T_marker": base_T_marker.tolist(),
        "size_mm": 120.0,
        "image": "vista-cabin-marker",
    }


class DemoError(RuntimeError):
    pass


def _demo_account(settings: Settings) -> tuple[str, str]:
    """A fresh API token and a fresh random password for the demo inspector (created on
    first use): no published password ever works on a real database."""
    import secrets
    from datetime import timedelta

    from sqlalchemy import select

    from supervisor.auth.service import hash_password
    from supervisor.db import Database
    from supervisor.models import User
    from supervisor.users.service import change_user, create_token, create_user

    password = secrets.token_urlsafe(12)
    password_hash = hash_password(password)
    db = Database(settings.resolved_database_url, sqlite_synchronous=settings.sqlite_synchronous)
    try:
        with db.write() as session:
            user = session.scalar(select(User).where(User.username == DEMO_USER))
            if user is None:
                user = create_user(
                    session, username=DEMO_USER, role="inspector", password_hash=password_hash
                )
            else:
                change_user(
                    session, user, actor=COMMAND_LINE, active=True, password_hash=password_hash
                )
            token = create_token(
                session, user=user, name="vista demo", kind="cli", ttl=timedelta(hours=24)
            )
            return token, password
    finally:
        db.dispose()


def run_demo(
    settings: Settings,
    *,
    spacing_mm: float,
    seed: int,
    timeout_s: float,
    say: Callable[[str], None],
) -> dict:
    """Simulate, upload, run and wait; the inspection, its run and its defects."""
    with warnings.catch_warnings():  # starlette's notice about its own test client's httpx
        warnings.filterwarnings("ignore", message=".*starlette.testclient.*")
        from fastapi.testclient import TestClient

    from supervisor.app import create_app
    from supervisor.migrate import upgrade

    secure_data_dir(settings)
    upgrade(settings.resolved_database_url, "head")
    secure_data_dir(settings)
    folder = settings.data_dir / "demo" / f"assembly-{seed}"
    (write_example,) = declared_hooks("DEMO_EXAMPLE")
    write_example(folder, spacing_mm=spacing_mm, seed=seed, say=say)
    token, password = _demo_account(settings)
    with TestClient(create_app(settings)) as client:
        client.headers["authorization"] = f"Bearer {token}"

        def call(method: str, url: str, **kwargs) -> dict:
            response = client.request(method, url, **kwargs)
            if response.status_code >= 400:
                raise DemoError(f"{method} {url}: {response.status_code} {response.text}")
            return response.json() if response.content else {}

        inspection = call(
            "POST",
            "/api/v1/inspections",
            json={
                "title": "Demo: cabin sidewall lining",
                "aircraft": "simulated",
                "area": "cabin",
                "tolerances": TOLERANCES,
                "markers": [_cabin_marker(folder / "truth.json")],
            },
        )
        base = f"/api/v1/inspections/{inspection['id']}"

        def upload(path: Path, kind: str, media_type: str) -> int:
            return call(
                "POST",
                f"{base}/artifacts",
                params={"kind": kind, "name": path.name},
                content=path.read_bytes(),
                headers={"content-type": media_type},
            )["id"]

        say("uploading the calibration pairs and the scans")
        pairs = upload(folder / "pairs.json", "pairs", "application/json")
        manifest = upload(folder / "scans.json", "scans", "application/json")
        scans = [upload(p, "scan", "application/x-ply") for p in sorted(folder.glob("scan_*.ply"))]
        run = call(
            "POST",
            f"{base}/runs",
            json={
                "name": "demo: calibrate → stitch → measure",
                "steps": [
                    {"name": "calibrate", "kind": "stitching.calibrate", "inputs": [pairs]},
                    {
                        "name": "stitch",
                        "kind": "stitching.stitch",
                        "inputs": [manifest, *scans],
                        "after": ["calibrate"],
                        "params": {"voxel_mm": 0.1},
                    },
                    {"name": "measure", "kind": "defects.measure", "after": ["stitch"]},
                ],
            },
        )
        run = _wait(call, run["id"], timeout_s, say)
        failed = [j for j in run["jobs"] if j["status"] != "succeeded"]
        if failed:
            job = failed[0]
            raise DemoError(f"job {job['id']} ({job['step']}) {job['status']}: {job['error']}")
        defects = call("GET", "/api/v1/defects", params={"run": run["id"], "limit": 500})["items"]
    return {
        "inspection": inspection,
        "run": run,
        "defects": defects,
        "folder": folder,
        "password": password,
    }


def _wait(call: Callable, run_id: int, timeout_s: float, say: Callable[[str], None]) -> dict:
    deadline = time.monotonic() + timeout_s
    shown = ""
    while True:
        run = call("GET", f"/api/v1/runs/{run_id}")
        running = [j for j in run["jobs"] if j["status"] in ("queued", "running", "waiting")]
        line = ", ".join(f"{j['step']} {j['status']} {j['progress']:.0%}" for j in run["jobs"])
        if line != shown:
            say(line)
            shown = line
        if not running:
            return run
        if time.monotonic() > deadline:
            raise DemoError(
                f"the run did not finish in {timeout_s:.0f} s ({line}); with a broker "
                "configured, start workers: vista worker --queues stitching,defects"
            )
        time.sleep(0.5)
