"""The audit log holds every change of state: each mutating route of the API is called as
a user would, and each leaves at least one audit row naming who acted — or, for a
judgment, a revision of it (judgments keep their own full history). A mutating route added
without an entry here fails the test: the walk covers all of them."""

from __future__ import annotations

import uuid
from collections.abc import Callable
from datetime import UTC, datetime

from fastapi.routing import APIRoute, iter_route_contexts
from sqlalchemy import func, select

from supervisor.models import AuditEvent, JudgmentRevision
from tests.conftest import auth
from tests.seeding import seed_defects

MUTATING = {"POST", "PUT", "PATCH", "DELETE"}


def _counts(runtime) -> tuple[int, int]:
    with runtime.db.read() as session:
        events = session.scalar(select(func.count()).select_from(AuditEvent))
        revisions = session.scalar(select(func.count()).select_from(JudgmentRevision))
    return events, revisions


def _last_event(runtime) -> AuditEvent:
    with runtime.db.read() as session:
        return session.scalars(select(AuditEvent).order_by(AuditEvent.id.desc())).first()


def test_every_mutating_route_leaves_an_audit_row(client, tokens, runtime):
    admin, ines = auth(tokens["admin"]), auth(tokens["inspector"])
    state: dict[str, int] = {}

    def inspection() -> int:
        if "inspection" not in state:
            made = client.post(
                "/api/v1/inspections", json={"title": "t", "area": "cabin"}, headers=ines
            )
            state["inspection"] = made.json()["id"]
        return state["inspection"]

    def trashed() -> int:
        made = client.post(
            "/api/v1/inspections", json={"title": "bin", "area": "cabin"}, headers=ines
        )
        assert (
            client.delete(f"/api/v1/inspections/{made.json()['id']}", headers=ines).status_code
            == 204
        )
        return made.json()["id"]

    def artifact() -> int:
        return client.post(
            f"/api/v1/inspections/{inspection()}/artifacts",
            params={"kind": "report", "name": f"{uuid.uuid4().hex}.json"},
            content=b"{}",
            headers={**ines, "Content-Type": "application/json"},
        ).json()["id"]

    def job() -> int:
        step = {"name": "s", "kind": "test.sleep", "params": {}, "after": []}
        run = client.post(
            f"/api/v1/inspections/{inspection()}/runs", json={"steps": [step]}, headers=ines
        )
        return run.json()["jobs"][0]["id"]

    def cancelled_job() -> int:
        job_id = job()
        client.post(f"/api/v1/jobs/{job_id}/cancel", headers=ines)
        return job_id

    def defect() -> int:
        return seed_defects(runtime, inspection(), 1)[0]

    def user() -> int:
        made = client.post(
            "/api/v1/users",
            json={
                "username": f"u{uuid.uuid4().hex[:8]}",
                "role": "viewer",
                "password": "pass-word-1",
            },
            headers=admin,
        )
        return made.json()["id"]

    def token() -> int:
        client.post(f"/api/v1/users/{user_id}/tokens", json={"name": "t"}, headers=admin)
        return client.get("/api/v1/tokens", headers=admin).json()["items"][-1]["id"]

    def tolerance_set() -> int:
        made = client.post(
            "/api/v1/tolerance-sets",
            json={"name": f"set {uuid.uuid4().hex[:8]}", "tolerances": {"step_mm": {"max": 1.0}}},
            headers=ines,
        )
        return made.json()["id"]

    made_sets = iter([tolerance_set() for _ in range(3)])  # made before the walk counts
    user_id = user()
    now = datetime.now(UTC).isoformat()
    calls: dict[tuple[str, str], Callable[[], object]] = {
        ("PUT", "/api/v1/defects/{defect_id}/judgments/me"): lambda: client.put(
            f"/api/v1/defects/{defect()}/judgments/me", json={"verdict": "confirmed"}, headers=ines
        ),
        ("POST", "/api/v1/sync/judgments"): lambda: client.post(
            "/api/v1/sync/judgments",
            json={
                "items": [
                    {
                        "client_id": uuid.uuid4().hex,
                        "defect_id": defect(),
                        "verdict": "rejected",
                        "client_time": now,
                    }
                ]
            },
            headers=ines,
        ),
        ("POST", "/api/v1/auth/token"): lambda: client.post(
            "/api/v1/auth/token", json={"username": "ivan", "password": "inspector-password"}
        ),
        ("DELETE", "/api/v1/auth/token"): lambda: client.delete(
            "/api/v1/auth/token",
            headers=auth(
                client.post(
                    "/api/v1/auth/token", json={"username": "vic", "password": "viewer-password"}
                ).json()["access_token"]
            ),
        ),
        ("PUT", "/api/v1/me/password"): lambda: client.put(
            "/api/v1/me/password",
            json={"current_password": "inspector-password", "new_password": "inspector-password-2"},
            headers=auth(tokens["inspector2"]),
        ),
        ("POST", "/api/v1/users"): user,
        ("PATCH", "/api/v1/users/{user_id}"): lambda: client.patch(
            f"/api/v1/users/{user()}", json={"role": "inspector"}, headers=admin
        ),
        ("POST", "/api/v1/users/{user_id}/tokens"): lambda: client.post(
            f"/api/v1/users/{user_id}/tokens", json={"name": "headset"}, headers=admin
        ),
        ("DELETE", "/api/v1/tokens/{token_id}"): lambda: client.delete(
            f"/api/v1/tokens/{token()}", headers=admin
        ),
        ("POST", "/api/v1/tokens/revoke"): lambda: (
            token(),
            client.post("/api/v1/tokens/revoke", json={"user_id": user_id}, headers=admin),
        ),
        ("POST", "/api/v1/inspections"): lambda: client.post(
            "/api/v1/inspections", json={"title": "another", "area": "cargo"}, headers=ines
        ),
        ("PATCH", "/api/v1/inspections/{inspection_id}"): lambda: client.patch(
            f"/api/v1/inspections/{inspection()}",
            json={"tolerances": {"gap_mm": {"min": 0.5, "max": 2.0}}},
            headers=ines,
        ),
        ("DELETE", "/api/v1/inspections/{inspection_id}"): trashed,
        ("POST", "/api/v1/tolerance-sets"): tolerance_set,
        ("PATCH", "/api/v1/tolerance-sets/{set_id}"): lambda: client.patch(
            f"/api/v1/tolerance-sets/{next(made_sets)}",
            json={"tolerances": {"step_mm": {"max": 0.7}}},
            headers=ines,
        ),
        ("DELETE", "/api/v1/tolerance-sets/{set_id}"): lambda: client.delete(
            f"/api/v1/tolerance-sets/{next(made_sets)}", headers=ines
        ),
        ("POST", "/api/v1/inspections/{inspection_id}/tolerance-set"): lambda: client.post(
            f"/api/v1/inspections/{inspection()}/tolerance-set",
            json={"set_id": next(made_sets)},
            headers=ines,
        ),
        ("POST", "/api/v1/trash/inspections/{inspection_id}/restore"): lambda: client.post(
            f"/api/v1/trash/inspections/{trashed()}/restore", headers=admin
        ),
        ("DELETE", "/api/v1/trash/inspections/{inspection_id}"): lambda: client.delete(
            f"/api/v1/trash/inspections/{trashed()}", params={"confirm": "yes"}, headers=admin
        ),
        ("POST", "/api/v1/inspections/{inspection_id}/artifacts"): artifact,
        ("DELETE", "/api/v1/inspections/{inspection_id}/artifacts/{artifact_id}"): lambda: (
            client.delete(
                f"/api/v1/inspections/{inspection()}/artifacts/{artifact()}", headers=ines
            )
        ),
        ("POST", "/api/v1/inspections/{inspection_id}/runs"): job,
        ("POST", "/api/v1/jobs/{job_id}/cancel"): cancelled_job,
        ("POST", "/api/v1/jobs/{job_id}/retry"): lambda: client.post(
            f"/api/v1/jobs/{cancelled_job()}/retry", headers=ines
        ),
        ("POST", "/api/v1/defects"): lambda: client.post(
            "/api/v1/defects",
            json={"inspection_id": inspection(), "type": "dent", "location_mm": [0, 0, 0]},
            headers=ines,
        ),
        ("POST", "/api/v1/defects/{defect_id}/notes"): lambda: client.post(
            f"/api/v1/defects/{defect()}/notes", json={"text": "seen from the ladder"}, headers=ines
        ),
        ("PATCH", "/api/v1/defects/{defect_id}"): lambda: client.patch(
            f"/api/v1/defects/{defect()}",
            json={"status": "dismissed", "reason": "glare"},
            headers=ines,
        ),
    }
    routes = {
        (method, route.path)
        for route in iter_route_contexts(client.app.routes)
        if isinstance(route.original_route, APIRoute)
        for method in route.methods & MUTATING
    }
    assert routes == set(calls), ("walk these too:", routes - set(calls), set(calls) - routes)
    missing = []
    for (method, path), call in calls.items():
        events, revisions = _counts(runtime)
        call()
        after_events, after_revisions = _counts(runtime)
        judged = "judgments" in path and after_revisions > revisions
        if after_events <= events and not judged:
            missing.append((method, path))
        elif after_events > events:
            assert _last_event(runtime).username, (method, path)
    assert not missing, missing
