from __future__ import annotations

import uuid
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime

import httpx
import pytest
from sqlalchemy import func, select

from supervisor.models import Judgment, JudgmentRevision
from tests.conftest import add_user, auth, make_settings
from tests.seeding import seed_defects


@pytest.fixture
def inspection(client, tokens) -> int:
    return client.post(
        "/api/v1/inspections",
        json={"title": "t", "area": "cabin"},
        headers=auth(tokens["inspector"]),
    ).json()["id"]


def test_filters_and_cursor_pages(client, tokens, inspection, runtime):
    ids = seed_defects(runtime, inspection, 45)
    headers = auth(tokens["viewer"])
    gaps, cursor = [], None
    while True:
        params = {"inspection": inspection, "type": "gap", "limit": 4}
        page = client.get(
            "/api/v1/defects",
            params={**params, **({"cursor": cursor} if cursor else {})},
            headers=headers,
        ).json()
        gaps += page["items"]
        cursor = page["next_cursor"]
        if not cursor:
            break
    assert [d["id"] for d in gaps] == ids[0::4]
    resolved = client.get(
        "/api/v1/defects", params={"status": "resolved", "limit": 500}, headers=headers
    )
    assert [d["id"] for d in resolved.json()["items"]] == ids[0::5]
    measurements = client.get(
        "/api/v1/defects", params={"severity": "info", "limit": 500}, headers=headers
    )
    assert [d["id"] for d in measurements.json()["items"]] == ids[0::3]
    assert (
        client.get("/api/v1/defects", params={"type": "crack"}, headers=headers).status_code == 422
    )
    assert (
        client.get("/api/v1/defects", params={"inspection": 999}, headers=headers).json()["items"]
        == []
    )


def test_manual_defect_and_status_workflow(client, tokens, inspection):
    created = client.post(
        "/api/v1/defects",
        json={
            "inspection_id": inspection,
            "type": "scratch",
            "location_mm": [1, 2, 3],
            "normal": [0, 0, 2],
        },
        headers=auth(tokens["inspector"]),
    )
    assert created.status_code == 201, created.text
    defect = created.json()
    assert defect["normal"] == [0, 0, 1] and defect["source"] == "manual"
    assert defect["consensus"]["total"] == 0 and not defect["consensus"]["needs_review"]
    patched = client.patch(
        f"/api/v1/defects/{defect['id']}",
        json={"status": "resolved"},
        headers=auth(tokens["inspector"]),
    )
    assert patched.json()["status"] == "resolved"
    nan = client.post(
        "/api/v1/defects",
        content=b'{"inspection_id": 1, "type": "dent", "location_mm": [NaN, 0, 0]}',
        headers={**auth(tokens["inspector"]), "content-type": "application/json"},
    )
    assert nan.status_code == 422


def test_judgment_revisions_history_and_consensus(client, tokens, inspection, runtime):
    (defect,) = seed_defects(runtime, inspection, 1)
    url = f"/api/v1/defects/{defect}/judgments/me"
    first = client.put(url, json={"verdict": "confirmed"}, headers=auth(tokens["inspector"])).json()
    assert first["judgment"]["revision"] == 1
    same = client.put(url, json={"verdict": "confirmed"}, headers=auth(tokens["inspector"])).json()
    assert same["judgment"]["revision"] == 1  # repeating a judgment changes nothing
    changed = client.put(
        url,
        json={"verdict": "reclassified", "new_type": "dent", "comment": "it is a dent"},
        headers=auth(tokens["inspector"]),
    ).json()
    assert changed["judgment"]["revision"] == 2
    client.put(url, json={"verdict": "rejected"}, headers=auth(tokens["inspector2"]))
    client.put(
        url, json={"verdict": "reclassified", "new_type": "dent"}, headers=auth(tokens["admin"])
    )
    _device_judges(client, tokens["device"], defect, {"verdict": "uncertain"})
    listing = client.get(
        f"/api/v1/defects/{defect}/judgments", headers=auth(tokens["viewer"])
    ).json()
    consensus = listing["consensus"]
    assert consensus["counts"] == {"confirmed": 0, "rejected": 1, "reclassified": 2, "uncertain": 1}
    assert consensus["majority"] == "reclassified" and consensus["agreement"] == 0.5
    assert consensus["needs_review"] and consensus["reclassified_as"] == {"dent": 2}
    mine = next(j for j in listing["judgments"] if j["username"] == "ines")
    assert [(h["revision"], h["verdict"]) for h in mine["history"]] == [
        (1, "confirmed"),
        (2, "reclassified"),
    ]
    retype = {"verdict": "reclassified", "new_type": "dent"}
    client.put(url, json=retype, headers=auth(tokens["inspector2"]))
    assert client.put(url, json=retype, headers=auth(tokens["device"])).status_code == 403
    _device_judges(client, tokens["device"], defect, retype)
    settled = client.get(f"/api/v1/defects/{defect}", headers=auth(tokens["viewer"])).json()[
        "consensus"
    ]
    assert settled["majority"] == "reclassified" and settled["agreement"] == 1.0
    assert not settled["needs_review"]


def _device_judges(client, token: str, defect_id: int, judgment: dict) -> None:
    """A headset's judgment goes through the sync (its token may not PUT)."""
    item = {
        "client_id": uuid.uuid4().hex,
        "defect_id": defect_id,
        "client_time": datetime.now(UTC).isoformat(),
        **judgment,
    }
    answer = client.post("/api/v1/sync/judgments", json={"items": [item]}, headers=auth(token))
    assert answer.status_code == 200 and answer.json()["results"][0]["status"] == "applied"


def test_judgment_rules(client, tokens, inspection, runtime):
    (defect,) = seed_defects(runtime, inspection, 1)  # a gap
    url = f"/api/v1/defects/{defect}/judgments/me"
    viewer = client.put(url, json={"verdict": "confirmed"}, headers=auth(tokens["viewer"]))
    assert viewer.status_code == 403 and "viewer" in viewer.json()["detail"]
    for body, phrase in [
        ({"verdict": "reclassified"}, "new_type is required"),
        ({"verdict": "confirmed", "new_type": "dent"}, "only given"),
        ({"verdict": "reclassified", "new_type": "gap"}, "already is a gap"),
        ({"verdict": "maybe"}, "verdict"),
        ({"verdict": "confirmed", "user_id": 1}, "user_id: is not a known field"),
    ]:
        response = client.put(url, json=body, headers=auth(tokens["inspector"]))
        assert response.status_code == 422, body
        assert phrase in response.json()["detail"], response.json()["detail"]
    assert (
        client.put(
            "/api/v1/defects/999/judgments/me",
            json={"verdict": "confirmed"},
            headers=auth(tokens["inspector"]),
        ).status_code
        == 404
    )
    # There is no way to address someone else's judgment: only /me exists.
    client.put(url, json={"verdict": "confirmed"}, headers=auth(tokens["inspector"]))
    client.put(url, json={"verdict": "rejected"}, headers=auth(tokens["inspector2"]))
    listing = client.get(
        f"/api/v1/defects/{defect}/judgments", headers=auth(tokens["viewer"])
    ).json()
    assert {j["username"]: j["verdict"] for j in listing["judgments"]} == {
        "ines": "confirmed",
        "ivan": "rejected",
    }
    assert client.put(
        f"/api/v1/defects/{defect}/judgments/2",
        json={"verdict": "rejected"},
        headers=auth(tokens["inspector"]),
    ).status_code in (404, 405)


CLIENTS = 32
WRITES_PER_CLIENT = 12


def test_32_concurrent_clients_lose_no_update(tmp_path, database_url, start_server):
    settings = make_settings(tmp_path, database_url)
    server = start_server(settings, run_engine=False)
    runtime = server.app.state.runtime
    tokens = [add_user(runtime, f"judge{n}", "inspector", "judge-password") for n in range(CLIENTS)]
    admin = add_user(runtime, "boss", "admin", "boss-password")
    inspection = httpx.post(
        f"{server.url}/api/v1/inspections",
        json={"title": "c", "area": "cargo"},
        headers=auth(admin),
    ).json()["id"]
    defects = seed_defects(runtime, inspection, 8)
    verdicts = ("confirmed", "rejected", "uncertain")

    def judge(number: int) -> dict[int, int]:
        expected: dict[int, int] = {}
        with httpx.Client(base_url=server.url, headers=auth(tokens[number]), timeout=60) as http:
            for write in range(WRITES_PER_CLIENT):
                defect = defects[(number + write) % len(defects)]
                body = {"verdict": verdicts[write % 3], "comment": f"client {number} write {write}"}
                response = http.put(f"/api/v1/defects/{defect}/judgments/me", json=body)
                assert response.status_code == 200, response.text
                expected[defect] = expected.get(defect, 0) + 1
                assert response.json()["judgment"]["revision"] == expected[defect]
        return expected

    with ThreadPoolExecutor(CLIENTS) as pool:
        results = list(pool.map(judge, range(CLIENTS)))
    with runtime.db.read() as session:
        rows = session.execute(
            select(Judgment.user_id, Judgment.defect_id, Judgment.revision)
        ).all()
        revisions = session.execute(
            select(
                JudgmentRevision.user_id,
                JudgmentRevision.defect_id,
                func.count(),
                func.max(JudgmentRevision.revision),
            ).group_by(JudgmentRevision.user_id, JudgmentRevision.defect_id)
        ).all()
    assert len(rows) == len({(u, d) for u, d, _ in rows}) == sum(len(r) for r in results)
    assert sum(r for _, _, r in rows) == CLIENTS * WRITES_PER_CLIENT
    assert all(count == top for _, _, count, top in revisions)
    assert sum(count for _, _, count, _ in revisions) == CLIENTS * WRITES_PER_CLIENT
