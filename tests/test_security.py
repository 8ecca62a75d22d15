"""Issue 31's probes, as an attacker and a careless colleague would try them: ids never
come back, tokens can be revoked and users deactivated (at the next request), only owners
and admins destroy, sign-in is rate limited, responses carry security headers, files are
private. Each fails on the code before the issue and passes after."""

from __future__ import annotations

import itertools
import re
import stat
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from tests.conftest import add_user, auth

SYNC = "/api/v1/sync"
BATCH = "/api/v1/sync/judgments"


def _inspection(client, token: str, **fields) -> int:
    body = {"title": "probe", "area": "cabin", **fields}
    response = client.post("/api/v1/inspections", json=body, headers=auth(token))
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _defect(client, token: str, inspection: int, kind: str = "dent", **fields) -> int:
    body = {"inspection_id": inspection, "type": kind, "location_mm": [0, 0, 0], **fields}
    response = client.post("/api/v1/defects", json=body, headers=auth(token))
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _purge(client, admin: str, inspection: int) -> None:
    assert (
        client.delete(f"/api/v1/inspections/{inspection}", headers=auth(admin)).status_code == 204
    )
    purged = client.delete(f"/api/v1/trash/inspections/{inspection}", headers=auth(admin))
    assert purged.status_code == 204


# --- 1. identities that never come back ------------------------------------------------


def test_ids_are_never_reused_and_an_old_verdict_never_lands_on_a_new_defect(client, tokens):
    ines, admin, device = tokens["inspector"], tokens["admin"], tokens["device"]
    old_inspection = _inspection(client, ines)
    old_defect = _defect(client, ines, old_inspection)
    pulled = client.get(SYNC, params={"inspection": old_inspection}, headers=auth(device)).json()
    _purge(client, admin, old_inspection)

    new_inspection = _inspection(client, ines)
    new_defect = _defect(client, ines, new_inspection, "scratch")
    assert (new_inspection, new_defect) != (old_inspection, old_defect)
    assert new_inspection > old_inspection and new_defect > old_defect

    # the headset's queued verdict for the old defect: refused, with a sentence
    verdict = {
        "client_id": "c-old-dent",
        "defect_id": old_defect,
        "inspection_id": old_inspection,
        "verdict": "confirmed",
        "comment": "dent on wing panel confirmed",
        "client_time": datetime.now(UTC).isoformat(),
    }
    result = client.post(BATCH, json={"items": [verdict]}, headers=auth(device)).json()
    assert result["results"][0]["status"] == "rejected"
    assert "set aside" in result["results"][0]["detail"]
    # the old cursor is refused for the new inspection and ends the deleted one
    stale = client.get(
        SYNC,
        params={"inspection": new_inspection, "since": pulled["next_cursor"]},
        headers=auth(device),
    )
    assert stale.status_code == 400 and "belongs to inspection" in stale.json()["detail"]
    gone = client.get(
        SYNC,
        params={"inspection": old_inspection, "since": pulled["next_cursor"]},
        headers=auth(device),
    )
    assert gone.status_code == 410


def test_a_verdict_for_a_defect_of_another_inspection_is_set_aside(client, tokens):
    ines, device = tokens["inspector"], tokens["device"]
    first, second = _inspection(client, ines), _inspection(client, ines)
    defect = _defect(client, ines, second)
    item = {
        "client_id": "c-elsewhere",
        "defect_id": defect,
        "inspection_id": first,
        "verdict": "confirmed",
        "client_time": datetime.now(UTC).isoformat(),
    }
    result = client.post(BATCH, json={"items": [item]}, headers=auth(device)).json()["results"][0]
    assert result["status"] == "rejected"
    assert f"inspection {second}, not in inspection {first}" in result["detail"]


# --- 2. tokens and users you can manage ------------------------------------------------


def test_sign_out_revokes_the_token_at_the_next_request(client, tokens):
    signed = client.post(
        "/api/v1/auth/token", json={"username": "ines", "password": "inspector-password"}
    )
    assert signed.status_code == 200
    assert signed.headers["cache-control"] == "no-store"
    token = signed.json()["access_token"]
    assert signed.json()["expires_at"] is not None
    assert client.get("/api/v1/me", headers=auth(token)).status_code == 200  # now cached
    assert client.delete("/api/v1/auth/token", headers=auth(token)).status_code == 204
    again = client.get("/api/v1/me", headers=auth(token))
    assert again.status_code == 401 and "revoked" in again.json()["detail"]
    admin = tokens["admin"]
    trail = client.get("/api/v1/audit", params={"entity": "token"}, headers=auth(admin)).json()
    ines = [(e["username"], e["action"]) for e in trail["items"] if e["username"] == "ines"]
    assert ines == [("ines", "issue"), ("ines", "revoke")]  # the sign-in and the sign-out


def test_revoking_tokens_by_id_user_and_device(client, tokens, runtime):
    admin, ines = tokens["admin"], tokens["inspector"]
    me = client.get("/api/v1/me", headers=auth(ines)).json()
    mine = client.get("/api/v1/tokens", headers=auth(ines)).json()["items"]
    assert [t["current"] for t in mine] == [True] and "token" not in mine[0]
    # an inspector sees only their own tokens and cannot revoke others'
    assert client.get("/api/v1/tokens", params={"user": 1}, headers=auth(ines)).status_code == 403
    others = client.post("/api/v1/tokens/revoke", json={"device": "x"}, headers=auth(ines))
    assert others.status_code == 403

    headset = client.post(
        f"/api/v1/users/{me['id']}/tokens",
        json={"name": "hololens-9", "kind": "device"},
        headers=auth(admin),
    ).json()
    lifetime = datetime.fromisoformat(headset["expires_at"]) - datetime.now(UTC)
    assert timedelta(days=29) < lifetime <= timedelta(days=30)  # every token expires
    assert client.get("/api/v1/me", headers=auth(headset["token"])).status_code == 200
    lost = client.post(
        "/api/v1/tokens/revoke",
        json={"device": "hololens-9", "reason": "headset lost"},
        headers=auth(admin),
    )
    assert lost.status_code == 200 and len(lost.json()["revoked"]) == 1
    assert client.get("/api/v1/me", headers=auth(headset["token"])).status_code == 401
    assert client.get("/api/v1/me", headers=auth(ines)).status_code == 200

    own = client.post("/api/v1/tokens/revoke", json={"user_id": me["id"]}, headers=auth(ines))
    assert own.status_code == 200
    assert client.get("/api/v1/me", headers=auth(ines)).status_code == 401
    trail = client.get("/api/v1/audit", params={"entity": "token"}, headers=auth(admin)).json()
    reasons = {event["reason"] for event in trail["items"] if event["action"] == "revoke"}
    assert "headset lost" in reasons


def test_a_deactivated_user_is_out_at_once_and_the_last_admin_stays(client, tokens):
    admin, ivan = tokens["admin"], tokens["inspector2"]
    ivan_id = client.get("/api/v1/me", headers=auth(ivan)).json()["id"]
    assert client.get("/api/v1/me", headers=auth(ivan)).status_code == 200  # cached
    off = client.patch(f"/api/v1/users/{ivan_id}", json={"active": False}, headers=auth(admin))
    assert off.status_code == 200 and off.json()["active"] is False
    assert client.get("/api/v1/me", headers=auth(ivan)).status_code == 401
    refused = client.post(
        "/api/v1/auth/token", json={"username": "ivan", "password": "inspector-password"}
    )
    assert refused.status_code == 401
    admin_id = client.get("/api/v1/me", headers=auth(admin)).json()["id"]
    last = client.patch(f"/api/v1/users/{admin_id}", json={"active": False}, headers=auth(admin))
    assert last.status_code == 409 and "last active admin" in last.json()["detail"]


def test_a_user_changes_their_own_password(client, tokens):
    ines = tokens["inspector"]
    wrong = client.put(
        "/api/v1/me/password",
        json={"current_password": "nope", "new_password": "a-new-password"},
        headers=auth(ines),
    )
    assert wrong.status_code == 403
    changed = client.put(
        "/api/v1/me/password",
        json={"current_password": "inspector-password", "new_password": "a-new-password"},
        headers=auth(ines),
    )
    assert changed.status_code == 204
    old = client.post(
        "/api/v1/auth/token", json={"username": "ines", "password": "inspector-password"}
    )
    new = client.post("/api/v1/auth/token", json={"username": "ines", "password": "a-new-password"})
    assert (old.status_code, new.status_code) == (401, 200)


# --- 3. who may destroy what -----------------------------------------------------------


def test_only_the_owner_or_an_admin_deletes_closes_or_changes_tolerances(client, tokens):
    ines, ivan, admin = tokens["inspector"], tokens["inspector2"], tokens["admin"]
    inspection = _inspection(client, ines)
    url = f"/api/v1/inspections/{inspection}"
    assert client.delete(url, headers=auth(ivan)).status_code == 403
    closed = client.patch(url, json={"status": "closed"}, headers=auth(ivan))
    assert closed.status_code == 403 and "owner" in closed.json()["detail"]
    wide = {"gap_mm": {"min": 0, "max": 1000}}
    assert client.patch(url, json={"tolerances": wide}, headers=auth(ivan)).status_code == 403
    assert (
        client.patch(url, json={"title": "renamed by ivan"}, headers=auth(ivan)).status_code == 200
    )
    assert client.patch(url, json={"status": "closed"}, headers=auth(ines)).status_code == 200
    assert client.patch(url, json={"status": "review"}, headers=auth(admin)).status_code == 200

    trail = client.get("/api/v1/audit", params={"inspection": inspection}, headers=auth(ines))
    changes = [(e["username"], e["action"], e["before"], e["after"]) for e in trail.json()["items"]]
    assert ("ivan", "update", {"title": "probe"}, {"title": "renamed by ivan"}) in changes
    assert ("ines", "update", {"status": "planned"}, {"status": "closed"}) in changes


def test_deletion_goes_to_a_trash_an_admin_restores_or_purges(client, tokens, runtime):
    ines, admin = tokens["inspector"], tokens["admin"]
    inspection = _inspection(client, ines)
    defect = _defect(client, ines, inspection)
    client.put(
        f"/api/v1/defects/{defect}/judgments/me",
        json={"verdict": "confirmed"},
        headers=auth(tokens["inspector2"]),
    )
    assert client.delete(f"/api/v1/inspections/{inspection}", headers=auth(ines)).status_code == 204
    for url in (f"/api/v1/inspections/{inspection}", f"/api/v1/defects/{defect}"):
        assert client.get(url, headers=auth(ines)).status_code == 404
    listed = client.get("/api/v1/inspections", headers=auth(ines)).json()["items"]
    assert inspection not in [i["id"] for i in listed]
    judged = client.put(
        f"/api/v1/defects/{defect}/judgments/me", json={"verdict": "rejected"}, headers=auth(ines)
    )
    assert judged.status_code == 404
    assert client.get("/api/v1/trash/inspections", headers=auth(ines)).status_code == 403
    trash = client.get("/api/v1/trash/inspections", headers=auth(admin)).json()["items"]
    assert [(t["id"], t["deleted_by"] is not None) for t in trash] == [(inspection, True)]

    restored = client.post(f"/api/v1/trash/inspections/{inspection}/restore", headers=auth(admin))
    assert restored.status_code == 200
    judgments = client.get(f"/api/v1/defects/{defect}/judgments", headers=auth(ines)).json()
    assert [j["verdict"] for j in judgments["judgments"]] == ["confirmed"]  # nothing lost
    _purge(client, admin, inspection)
    assert client.get(f"/api/v1/defects/{defect}", headers=auth(admin)).status_code == 404
    actions = [
        e["action"]
        for e in client.get(
            "/api/v1/audit", params={"inspection": inspection}, headers=auth(admin)
        ).json()["items"]
    ]
    assert actions[-4:] == ["delete", "restore", "delete", "purge"]


def test_nothing_of_a_trashed_inspection_is_read_through_another_route(client, tokens):
    """Every GET route that takes the id of an inspection, its artifact, run, job or
    defect answers 404 once the inspection is in the trash, as ``GET /jobs/{id}`` does
    (``GET /jobs/{id}/events`` streamed the job's params, result and inputs)."""
    from fastapi.routing import APIRoute, iter_route_contexts

    ines = tokens["inspector"]
    inspection = _inspection(client, ines)
    artifact = client.post(
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": "report", "name": "r.json"},
        content=b"{}",
        headers={**auth(ines), "Content-Type": "application/json"},
    ).json()["id"]
    step = {"name": "s", "kind": "test.sleep", "params": {}, "after": []}
    run = client.post(
        f"/api/v1/inspections/{inspection}/runs", json={"steps": [step]}, headers=auth(ines)
    ).json()
    ids = {
        "inspection_id": inspection,
        "artifact_id": artifact,
        "run_id": run["id"],
        "job_id": run["jobs"][0]["id"],
        "defect_id": _defect(client, ines, inspection),
    }
    cancel = client.post(f"/api/v1/jobs/{ids['job_id']}/cancel", headers=auth(ines))
    assert cancel.status_code == 200  # a finished job's stream ends: its inspection may go
    assert client.delete(f"/api/v1/inspections/{inspection}", headers=auth(ines)).status_code == 204
    checked = []
    for route in iter_route_contexts(client.app.routes):
        names = re.findall(r"\{(\w+)\}", route.path or "")
        if not isinstance(route.original_route, APIRoute) or "GET" not in route.methods:
            continue
        if not names or route.path.startswith("/api/v1/trash") or not set(names) <= set(ids):
            continue
        url = re.sub(r"\{(\w+)\}", lambda m: str(ids[m.group(1)]), route.path)
        answer = client.get(url, headers=auth(ines))
        assert answer.status_code == 404, (url, answer.status_code, answer.text[:200])
        checked.append(route.path)
    assert len(checked) >= 12, checked


def test_dismissing_records_who_and_why_and_critical_needs_the_owner(client, tokens):
    ines, ivan = tokens["inspector"], tokens["inspector2"]
    inspection = _inspection(client, ines)
    critical = _defect(client, ines, inspection, severity="critical")
    url = f"/api/v1/defects/{critical}"
    silent = client.patch(url, json={"status": "dismissed"}, headers=auth(ivan))
    assert silent.status_code == 422 and "reason" in silent.json()["detail"]
    other = client.patch(url, json={"status": "dismissed", "reason": "glare"}, headers=auth(ivan))
    assert other.status_code == 403
    owner = client.patch(
        url, json={"status": "dismissed", "reason": "glare on the lens"}, headers=auth(ines)
    )
    assert owner.status_code == 200
    body = owner.json()
    assert body["status_reason"] == "glare on the lens" and body["status_by"] is not None


# --- 7. sign-in cannot be used against the API ----------------------------------------


def test_failed_sign_ins_are_rate_limited_per_account(runtime_factory, tmp_path, sqlite_url):
    from tests.conftest import make_settings

    client, tokens, _ = runtime_factory(
        make_settings(tmp_path, sqlite_url, sign_in_per_account_per_min=3)
    )
    wrong = {"username": "ines", "password": "wrong-password"}
    codes = [client.post("/api/v1/auth/token", json=wrong).status_code for _ in range(4)]
    assert codes == [401, 401, 401, 429]
    limited = client.post(
        "/api/v1/auth/token", json={"username": "ines", "password": "inspector-password"}
    )
    assert limited.status_code == 429 and int(limited.headers["retry-after"]) >= 1
    assert "try again in" in limited.json()["detail"]
    assert client.get("/api/v1/me", headers=auth(tokens["inspector"])).status_code == 200


# --- 10. headers and files ------------------------------------------------------------


def test_every_response_carries_the_security_headers(client, tokens):
    for response in (
        client.get("/api/v1/inspections", headers=auth(tokens["viewer"])),
        client.get("/api/v1/inspections"),  # a 401
        client.get("/docs"),
    ):
        assert response.headers["x-content-type-options"] == "nosniff"
        assert response.headers["referrer-policy"] == "no-referrer"
        assert "frame-ancestors 'none'" in response.headers["content-security-policy"]


def test_the_data_folder_and_database_are_private(sqlite_url, tmp_path, runtime_factory):
    from tests.conftest import make_settings

    settings = make_settings(tmp_path, sqlite_url)
    client, _, _ = runtime_factory(settings)
    assert stat.S_IMODE(settings.data_dir.stat().st_mode) == 0o700
    database = Path(sqlite_url.removeprefix("sqlite:///"))
    assert stat.S_IMODE(database.stat().st_mode) == 0o600


@pytest.mark.parametrize("role", ["viewer", "device"])
def test_readers_cannot_delete_or_restore(client, tokens, role):
    inspection = _inspection(client, tokens["inspector"])
    assert (
        client.delete(f"/api/v1/inspections/{inspection}", headers=auth(tokens[role])).status_code
        == 403
    )
    restore = client.post(
        f"/api/v1/trash/inspections/{inspection}/restore", headers=auth(tokens[role])
    )
    assert restore.status_code == 403


def test_a_token_made_without_a_lifetime_by_the_command_line_expires(runtime):
    token = add_user(runtime, "cli-person", "inspector", "cli-person-password")
    from supervisor.auth.service import token_digest
    from supervisor.models import ApiToken

    with runtime.db.read() as session:
        row = session.query(ApiToken).filter_by(token_sha256=token_digest(token)).one()
    assert row.expires_at is not None


def test_password_check_slots_are_shared_by_every_process_of_the_machine(tmp_path):
    from supervisor.auth.limits import PasswordSlots

    first, second = PasswordSlots(tmp_path, 1), PasswordSlots(tmp_path, 1)  # two API processes
    held = first.try_take()
    assert held is not None and second.try_take() is None
    first.give_back(held)
    assert second.try_take() is not None


def test_a_password_hashed_with_older_parameters_is_re_hashed_at_sign_in(client, runtime):
    from argon2 import PasswordHasher
    from sqlalchemy import select

    from supervisor.models import User
    from supervisor.users.service import create_user

    four_lanes = PasswordHasher(parallelism=4).hash("older-password")  # argon2-cffi's default
    with runtime.db.write() as session:
        create_user(session, username="olga", role="viewer", password_hash=four_lanes)
    signed = client.post(
        "/api/v1/auth/token", json={"username": "olga", "password": "older-password"}
    )
    assert signed.status_code == 200
    with runtime.db.read() as session:
        stored = session.scalar(select(User.password_hash).where(User.username == "olga"))
    assert "p=1$" in stored and stored != four_lanes


def _readme_permissions() -> dict[str, list[bool]]:
    """The README's "Who may do what" table: per action, whether each column (admin,
    owner, other inspector, viewer, device) may (anything but "–")."""
    text = (Path(__file__).parents[1] / "README.md").read_text()
    table = text.split("### Who may do what", 1)[1].split("\n\n", 2)[1]
    rows = [line.split("|")[1:-1] for line in table.splitlines()[2:]]
    return {cells[0].strip(): [c.strip() != "–" for c in cells[1:]] for cells in rows}


def test_the_readme_permission_table_is_what_the_api_does(client, tokens):
    """Each row of the README's table that one request decides, asked of every column's
    user: refused (403) exactly where the table says "–" (it said a device may PUT a
    judgment, which answers 403, and not that it may list its tokens)."""
    owner, other = tokens["inspector"], tokens["inspector2"]
    inspection = _inspection(client, owner)
    defect = _defect(client, owner, inspection)
    now = datetime.now(UTC).isoformat()
    item = {"client_id": "x", "defect_id": defect, "verdict": "confirmed", "client_time": now}
    wider = itertools.count(1)  # each user's change a change (the same value changes nothing)
    probes = {
        "read inspections, defects, runs, files, scenes; sync": lambda h: client.get(
            f"/api/v1/defects/{defect}", headers=h
        ),
        "judge a defect online (`PUT …/judgments/me`)": lambda h: client.put(
            f"/api/v1/defects/{defect}/judgments/me", json={"verdict": "confirmed"}, headers=h
        ),
        "judge defects by sync push (`POST /sync/judgments`)": lambda h: client.post(
            "/api/v1/sync/judgments", json={"items": [item]}, headers=h
        ),
        "create inspections, upload, start/cancel/retry runs, report defects, rename, edit markers": (
            lambda h: client.post(
                "/api/v1/inspections", json={"title": "p", "area": "cabin"}, headers=h
            )
        ),
        "change an inspection's tolerances (by hand or from a set), close or reopen it": lambda h: (
            client.patch(
                f"/api/v1/inspections/{inspection}",
                json={"tolerances": {"gap_mm": {"min": 0.5, "max": 2.0 + next(wider)}}},
                headers=h,
            )
        ),
        "make a tolerance set (`POST /tolerance-sets`); change or delete one you made": (
            lambda h: client.post(
                "/api/v1/tolerance-sets",
                json={"name": f"set {next(wider)}", "tolerances": {}},
                headers=h,
            )
        ),
        "restore or purge the trash, manage users, any token": lambda h: client.get(
            "/api/v1/users", headers=h
        ),
        "list your own tokens (`GET /tokens`), sign out": lambda h: client.get(
            "/api/v1/tokens", headers=h
        ),
        "revoke your own tokens, change your password": lambda h: client.delete(
            "/api/v1/tokens/999999",
            headers=h,  # 404 where it may, 403 where it may not
        ),
    }
    table = _readme_permissions()
    columns = [tokens["admin"], owner, other, tokens["viewer"], tokens["device"]]
    assert set(probes) <= set(table), set(probes) - set(table)
    for action, probe in probes.items():
        answered = [probe(auth(token)).status_code for token in columns]
        assert [code != 403 for code in answered] == table[action], (action, answered)
