"""Headset sync: cursors, snapshots in pages, incremental changes, offline batches."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime, timedelta
from types import SimpleNamespace

import pytest
from sqlalchemy import func, select, update

from supervisor.judgments.schemas import JudgmentIn
from supervisor.judgments.write import JudgmentWrite, Written, write
from supervisor.models import Change, Defect, JudgmentRevision
from supervisor.sync.service import GAP_SETTLE_S, _settled
from tests.conftest import auth
from tests.seeding import seed_defects

SYNC = "/api/v1/sync"
BATCH = "/api/v1/sync/judgments"


@pytest.fixture
def inspection(client, tokens) -> int:
    return client.post(
        "/api/v1/inspections",
        json={"title": "sidewall", "area": "cabin"},
        headers=auth(tokens["inspector"]),
    ).json()["id"]


def _sync(client, token, inspection, since=None, **params):
    answer = client.get(
        SYNC, params={"inspection": inspection, "since": since, **params}, headers=auth(token)
    )
    assert answer.status_code == 200, answer.text
    return answer.json()


def _item(defect_id, verdict="confirmed", *, at: datetime, client_id=None, **extra) -> dict:
    return {
        "client_id": client_id or uuid.uuid4().hex,
        "defect_id": defect_id,
        "verdict": verdict,
        "client_time": at.isoformat(),
        **extra,
    }


def test_full_then_incremental_sync_returns_only_what_changed(client, tokens, inspection, runtime):
    ids = seed_defects(runtime, inspection, 5)
    put = client.put(
        f"/api/v1/defects/{ids[0]}/judgments/me",
        json={"verdict": "rejected"},
        headers=auth(tokens["inspector"]),
    )
    assert put.status_code == 200
    device = tokens["device"]
    full = _sync(client, device, inspection)
    assert full["inspection"]["id"] == inspection and not full["more"]
    assert [d["id"] for d in full["defects"]] == ids
    assert [(j["defect_id"], j["verdict"]) for j in full["judgments"]] == [(ids[0], "rejected")]
    assert [(c["defect_id"], c["majority"]) for c in full["consensus"]] == [(ids[0], "rejected")]
    assert full["defects"][2]["location_mm"] == [2.0, 0.0, 0.0]

    quiet = _sync(client, device, inspection, full["next_cursor"])
    assert quiet["defects"] == quiet["judgments"] == quiet["consensus"] == []
    assert quiet["inspection"] is None and quiet["scene_etag"] == full["scene_etag"]

    client.put(
        f"/api/v1/defects/{ids[3]}/judgments/me",
        json={"verdict": "confirmed", "comment": "seen on site"},
        headers=auth(tokens["inspector2"]),
    )
    one = _sync(client, device, inspection, quiet["next_cursor"])
    assert one["defects"] == [] and one["inspection"] is None
    assert [(j["defect_id"], j["username"], j["comment"]) for j in one["judgments"]] == [
        (ids[3], "ivan", "seen on site")
    ]
    assert [(c["defect_id"], c["counts"]["confirmed"]) for c in one["consensus"]] == [(ids[3], 1)]
    assert one["scene_etag"] == quiet["scene_etag"]  # a judgment travels here, not in the scene

    client.patch(
        f"/api/v1/defects/{ids[1]}", json={"status": "resolved"}, headers=auth(tokens["inspector"])
    )
    client.patch(
        f"/api/v1/inspections/{inspection}", json={"status": "review"}, headers=auth(device)
    )  # refused: a device token does not change inspections
    status = _sync(client, device, inspection, one["next_cursor"])
    assert [(d["id"], d["status"]) for d in status["defects"]] == [(ids[1], "resolved")]
    assert status["judgments"] == [] and status["inspection"] is None


def test_defects_carry_value_unit_and_tolerance_once(client, tokens, inspection, runtime):
    seam, patch = seed_defects(runtime, inspection, 2)
    colour = {"value": 7.5, "unit": "delta_e", "tolerance": 5.0, "area_mm2": 42.0}
    with runtime.db.write() as session:
        session.execute(
            update(Defect)
            .where(Defect.id == patch)
            .values(type="color", value_mm=None, tolerance_mm=None, measurements=colour)
        )
    defects = {d["id"]: d for d in _sync(client, tokens["device"], inspection)["defects"]}
    assert {k: defects[seam][k] for k in ("value", "unit", "tolerance")} == {
        "value": 1.0,
        "unit": "mm",
        "tolerance": 1.0,
    }
    assert defects[patch]["value"] == 7.5 and defects[patch]["unit"] == "delta_e"
    assert defects[patch]["tolerance"] == 5.0
    assert defects[patch]["measurements"] == {"area_mm2": 42.0}
    assert not {"value_mm", "tolerance_mm"} & defects[seam].keys()
    assert datetime.fromisoformat(defects[seam]["created_at"]).microsecond == 0


def test_full_sync_in_pages_replays_what_changed_meanwhile(client, tokens, inspection, runtime):
    ids = seed_defects(runtime, inspection, 5)
    viewer = tokens["viewer"]
    first = _sync(client, viewer, inspection, limit=2)
    assert [d["id"] for d in first["defects"]] == ids[:2] and first["more"]
    client.put(
        f"/api/v1/defects/{ids[0]}/judgments/me",
        json={"verdict": "uncertain"},
        headers=auth(tokens["inspector"]),
    )
    second = _sync(client, viewer, inspection, first["next_cursor"], limit=2)
    third = _sync(client, viewer, inspection, second["next_cursor"], limit=2)
    assert [d["id"] for d in second["defects"] + third["defects"]] == ids[2:]
    assert second["inspection"] is None and not third["more"]
    after = _sync(client, viewer, inspection, third["next_cursor"])
    assert [(j["defect_id"], j["verdict"]) for j in after["judgments"]] == [(ids[0], "uncertain")]


def test_offline_batch_is_idempotent_and_last_writer_wins(client, tokens, inspection, runtime):
    a, b, c = seed_defects(runtime, inspection, 3)
    device = tokens["inspector"]  # the same person on two devices: web and headset
    now = datetime.now(UTC)
    batch = {
        "items": [
            _item(a, "confirmed", at=now - timedelta(minutes=30), comment="offline"),
            _item(b, "reclassified", at=now - timedelta(minutes=20), new_type="dent"),
            _item(a, "rejected", at=now - timedelta(minutes=40)),  # older than the first
        ]
    }
    first = client.post(BATCH, json=batch, headers=auth(device))
    assert first.status_code == 200, first.text
    results = first.json()["results"]
    assert [r["status"] for r in results] == ["applied", "applied", "stale"]
    assert (
        results[0]["judgment"]["comment"] == "offline" and results[0]["judgment"]["revision"] == 1
    )
    assert {x["defect_id"]: x["majority"] for x in first.json()["consensus"]} == {
        a: "confirmed",
        b: "reclassified",
    }
    retry = client.post(BATCH, json=batch, headers=auth(device)).json()["results"]
    assert [(r["status"], r["replayed"]) for r in retry] == [
        ("applied", True),
        ("applied", True),
        ("stale", True),
    ]
    history = client.get(f"/api/v1/defects/{a}/judgments", headers=auth(device)).json()
    assert [h["revision"] for h in history["judgments"][0]["history"]] == [1]

    # Online edit now; an offline edit made before it arrives later and loses.
    client.put(
        f"/api/v1/defects/{c}/judgments/me", json={"verdict": "rejected"}, headers=auth(device)
    )
    late = [_item(c, "confirmed", at=now - timedelta(minutes=5))]
    newer = [_item(a, "uncertain", at=now + timedelta(seconds=1))]
    answer = client.post(BATCH, json={"items": late + newer}, headers=auth(device)).json()
    assert [r["status"] for r in answer["results"]] == ["stale", "applied"]
    assert answer["results"][0]["judgment"]["verdict"] == "rejected"
    assert answer["results"][1]["judgment"]["revision"] == 2

    same = [_item(a, "uncertain", at=now + timedelta(seconds=2))]
    assert (
        client.post(BATCH, json={"items": same}, headers=auth(device)).json()["results"][0][
            "status"
        ]
        == "unchanged"
    )
    reused = dict(batch["items"][0], comment="another text")
    bad = [
        reused,
        _item(999_999, at=now),
        _item(b, "reclassified", at=now, new_type="step"),
        _item(b, at=now + timedelta(hours=1)),
    ]
    rejected = client.post(BATCH, json={"items": bad}, headers=auth(device)).json()["results"]
    assert [r["status"] for r in rejected] == ["rejected"] * 4
    details = [r["detail"] for r in rejected]
    assert "already used" in details[0] and "no defect with id 999999" in details[1]
    assert "already is a step" in details[2] and "ahead of the server's clock" in details[3]


def test_bad_sync_input_is_refused_and_changes_nothing(client, tokens, inspection, runtime):
    (defect,) = seed_defects(runtime, inspection, 1)
    device = tokens["device"]
    now = datetime.now(UTC)
    for body, phrase in [
        ({"items": []}, "at least 1"),
        ({"items": [_item(defect, at=now) | {"client_time": "2026-01-01T10:00:00"}]}, "time zone"),
        ({"items": [_item(defect, "reclassified", at=now)]}, "new_type is required when"),
        ({"items": [_item(defect, at=now)] * 1001}, "at most 1000"),
    ]:
        answer = client.post(BATCH, json=body, headers=auth(device))
        assert answer.status_code == 422 and phrase in answer.text, answer.text
    assert (
        client.get(f"/api/v1/defects/{defect}/judgments", headers=auth(device)).json()["judgments"]
        == []
    )
    viewer = client.post(
        BATCH, json={"items": [_item(defect, at=now)]}, headers=auth(tokens["viewer"])
    )
    assert viewer.status_code == 403
    bad_cursor = client.get(
        SYNC, params={"inspection": inspection, "since": "xyz"}, headers=auth(device)
    )
    assert bad_cursor.status_code == 400 and "since=0" in bad_cursor.json()["detail"]
    missing = client.get(SYNC, params={"inspection": 4242}, headers=auth(device))
    assert missing.status_code == 404
    cursor = _sync(client, device, inspection)["next_cursor"]
    client.delete(f"/api/v1/inspections/{inspection}", headers=auth(tokens["inspector"]))
    gone = client.get(
        SYNC, params={"inspection": inspection, "since": cursor}, headers=auth(device)
    )
    assert gone.status_code == 410 and "deleted" in gone.json()["detail"]


def test_device_tokens_only_read_and_sync(client, tokens, inspection, runtime):
    (defect,) = seed_defects(runtime, inspection, 1)
    device = auth(tokens["device"])
    assert client.get(f"/api/v1/defects/{defect}", headers=device).status_code == 200
    for method, url, body in [
        ("PUT", f"/api/v1/defects/{defect}/judgments/me", {"verdict": "confirmed"}),
        ("POST", "/api/v1/inspections", {"title": "x", "area": "cabin"}),
        ("PATCH", f"/api/v1/defects/{defect}", {"status": "resolved"}),
    ]:
        answer = client.request(method, url, json=body, headers=device)
        assert answer.status_code == 403 and "only read and sync" in answer.json()["detail"]


def test_sync_compresses_when_asked(client, tokens, inspection, runtime):
    seed_defects(runtime, inspection, 200)
    plain = client.get(
        SYNC,
        params={"inspection": inspection},
        headers={**auth(tokens["device"]), "Accept-Encoding": "identity"},
    )
    packed = client.get(
        SYNC,
        params={"inspection": inspection},
        headers={**auth(tokens["device"]), "Accept-Encoding": "gzip"},
    )
    assert "content-encoding" not in plain.headers
    assert packed.headers["content-encoding"] == "gzip" and packed.json() == plain.json()
    assert int(packed.headers["content-length"]) < len(plain.content) / 4


def test_cursor_waits_at_a_young_hole_in_the_log():
    now = datetime.now(UTC)
    row = lambda seq, age_s: SimpleNamespace(seq=seq, created_at=now - timedelta(seconds=age_s))  # noqa: E731
    assert [r.seq for r in _settled([row(11, 1), row(12, 1)], 10, now)] == [11, 12]
    # 12 is missing and 13 is young: 12 may still be committing
    assert [r.seq for r in _settled([row(11, 1), row(13, 1)], 10, now)] == [11]
    # old enough: 12 was rolled back
    old = GAP_SETTLE_S + 1
    assert [r.seq for r in _settled([row(11, old), row(13, old)], 10, now)] == [11, 13]


def _exactly(model, document: dict, absent: tuple[str, ...] = ()) -> None:  # a pydantic model
    """``document`` is what ``model`` declares: it validates, with no field more or less
    (but those ``absent``, which it leaves out)."""
    model.model_validate(document)
    expected = set(model.model_fields) - set(absent)
    assert set(document) == expected, (model.__name__, sorted(document))


def test_the_served_pages_are_the_declared_response_models(client, tokens, inspection, runtime):
    """The sync writes its JSON itself (fast); the documents are exactly SyncOut and
    BatchOut, field for field, so the OpenAPI document cannot drift from them."""
    from supervisor.judgments.schemas import JudgmentOut
    from supervisor.sync.schemas import BatchOut, ItemResult, SyncConsensus, SyncDefect, SyncOut
    from supervisor.sync.service import LINEAGE_KEYS

    ids = seed_defects(runtime, inspection, 3)
    now = datetime.now(UTC)
    pushed = client.post(
        BATCH, json={"items": [_item(ids[0], at=now)]}, headers=auth(tokens["inspector"])
    ).json()
    _exactly(BatchOut, pushed)
    _exactly(ItemResult, pushed["results"][0])
    for since in (None, "0"):
        page = _sync(client, tokens["viewer"], inspection, since)
        _exactly(SyncOut, page)
        _exactly(SyncDefect, page["defects"][0], absent=(*LINEAGE_KEYS, "notes"))  # plain
        _exactly(JudgmentOut, page["judgments"][0])
        _exactly(SyncConsensus, page["consensus"][0])
    later = _sync(client, tokens["viewer"], inspection, page["next_cursor"])
    _exactly(SyncOut, later)


def test_the_one_judgment_write_keeps_a_later_judgment_for_the_sync(
    client, tokens, inspection, runtime
):
    """PUT and sync push share one write: a change bumps the revision with its revision and
    change-log rows, the same judgment again adds nothing, the sync's write keeps a judgment
    made later (a PUT that lands while a batch is being applied), and a reclassification
    to the defect's own type is refused by the same rule on both paths."""
    (defect,) = seed_defects(runtime, inspection, 1)  # a gap
    user_id = client.get("/api/v1/me", headers=auth(tokens["device"])).json()["id"]
    now = datetime.now(UTC)

    def put(verdict: str, *, at: datetime, newer_only: bool = False, new_type=None) -> Written:
        given = JudgmentIn(verdict=verdict, new_type=new_type)
        judgment = JudgmentWrite.of(
            given, defect_id=defect, user_id=user_id, client_time=at, now=now, newer_only=newer_only
        )
        with runtime.db.write() as session:
            return write(session, judgment)

    first = put("confirmed", at=now)
    assert first.changed and first.judgment.revision == 1 and first.votes == [("confirmed", None)]
    again = put("confirmed", at=now + timedelta(seconds=1))
    assert not again.changed and again.judgment.revision == 1
    late = put("rejected", at=now - timedelta(minutes=1), newer_only=True)
    assert not late.changed and late.judgment.verdict == "confirmed"
    later = put("rejected", at=now + timedelta(minutes=1), newer_only=True)
    assert later.changed and later.judgment.revision == 2
    own_type = put("reclassified", at=now + timedelta(minutes=2), new_type="gap")
    assert own_type.refused and not own_type.changed and own_type.defect_type == "gap"
    with runtime.db.read() as session:
        revisions = session.scalars(select(JudgmentRevision.revision)).all()
        logged = session.scalar(
            select(func.count()).select_from(Change).where(Change.entity == "judgment")
        )
    assert sorted(revisions) == [1, 2] and logged == 2
    missing = JudgmentWrite.of(
        JudgmentIn(verdict="confirmed"),
        defect_id=999_999,
        user_id=user_id,
        client_time=now,
        now=now,
    )
    with runtime.db.write() as session:
        assert write(session, missing).defect_type is None
