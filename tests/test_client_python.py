"""The Python SDK and the headset simulator against a live supervisor: offline work,
reconnect, conflicting edits from the web and a second headset, a lost response retried."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

import httpx
import pytest
from vista_client import Headset, HeadsetOffline, VistaClient, VistaError

from tests.conftest import add_user
from tests.seeding import seed_defects


class LosingTransport(httpx.HTTPTransport):
    """Delivers the next ``lose`` requests but loses their responses (a dropped link)."""

    def __init__(self) -> None:
        super().__init__()
        self.lose = 0

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        response = super().handle_request(request)
        if self.lose:
            self.lose -= 1
            response.read()
            raise httpx.ReadError("connection reset while reading the response")
        return response


@pytest.fixture
def live(live_api):
    _, runtime, _ = live_api
    add_user(runtime, "ines", "inspector", "ines-pw")
    add_user(runtime, "ivan", "inspector", "ivan-pw")
    return live_api


def test_headset_offline_reconnect_conflicts_and_retries(live, tmp_path):
    server, runtime, admin_token = live
    admin = VistaClient(server.url, admin_token)
    ines_id = next(u["id"] for u in admin.users() if u["username"] == "ines")
    device_token = admin.create_token(ines_id, "hololens-7", kind="device")
    web = VistaClient(server.url)
    web.sign_in("ines", "ines-pw")
    ivan = VistaClient(server.url)
    ivan.sign_in("ivan", "ivan-pw")
    inspection = web.create_inspection("A320 cabin", "cabin")["id"]
    ids = seed_defects(runtime, inspection, 30)

    transport = LosingTransport()
    now = datetime.now(UTC)
    headset = Headset(VistaClient(server.url, device_token, transport=transport), inspection)
    first = headset.sync()
    assert (first.defects, first.judgments, first.scene) == (30, 0, "first")
    assert headset.load_scene()[:4] == b"glTF" and headset.load_scene() is None  # 304
    with pytest.raises(VistaError) as refused:
        headset.client.judge(ids[0], "confirmed")
    assert refused.value.status == 403  # a device token only reads and syncs

    # Offline: three judgments queued, shown locally at once.
    headset.go_offline()
    headset.judge(ids[0], "confirmed", at=now - timedelta(minutes=10))
    headset.judge(ids[1], "rejected", comment="reflection", at=now - timedelta(minutes=9))
    headset.judge(ids[2], "reclassified", new_type="dent", at=now - timedelta(minutes=8))
    assert headset.judgment_of(ids[1], ines_id)["comment"] == "reflection"
    assert (ids[1], ines_id) not in headset.judgments  # the server has not answered yet
    with pytest.raises(HeadsetOffline):
        headset.push()
    headset.save(tmp_path / "headset.json")  # the headset restarts while offline
    headset = Headset.load(
        VistaClient(server.url, device_token, transport=transport), tmp_path / "headset.json"
    )
    assert len(headset.outbox) == 3

    # Meanwhile on the web: Ines changes her mind about defect 0 later than the headset;
    # Ivan judges defect 1.
    web.judge(ids[0], "rejected", comment="checked with a gauge")
    ivan.judge(ids[1], "confirmed")

    # Reconnect; the first push reaches the server but its answer is lost.
    transport.lose = 1
    with pytest.raises(HeadsetOffline):
        headset.push()
    assert len(headset.outbox) == 3
    pushed = headset.push()  # the retry: answered as the first time
    assert [(r["status"], r["replayed"]) for r in pushed.results] == [
        ("stale", True),
        ("applied", True),
        ("applied", True),
    ]
    assert headset.outbox == []
    assert headset.judgment_of(ids[0], ines_id)["verdict"] == "rejected"  # the web's, later
    history = web.judgments(ids[1])
    mine = next(j for j in history["judgments"] if j["username"] == "ines")
    assert mine["revision"] == 1 and mine["comment"] == "reflection"
    assert history["consensus"]["counts"]["confirmed"] == 1
    assert history["consensus"]["counts"]["rejected"] == 1

    # The incremental sync brings Ivan's judgment and the consensus, nothing else.
    pulled = headset.sync()
    assert pulled.defects == 0
    assert headset.judgments[(ids[1], ivan.me()["id"])]["verdict"] == "confirmed"
    assert headset.consensus[ids[1]]["needs_review"] is True

    # Two headsets of the same person edit defect 3 offline; the later edit wins, whatever
    # the order they reconnect in.
    other = Headset(VistaClient(server.url, device_token), inspection)
    other.sync()
    other.judge(ids[3], "uncertain", at=now - timedelta(minutes=1))
    headset.judge(ids[3], "confirmed", at=now - timedelta(minutes=2))
    assert other.push().results[0]["status"] == "applied"
    late = headset.push().results[0]
    assert late["status"] == "stale" and late["judgment"]["verdict"] == "uncertain"
    assert web.judgments(ids[3])["judgments"][0]["verdict"] == "uncertain"
    pulled = headset.sync()  # the consensus changed: a sync page, not a new scene
    assert pulled.scene == "unchanged" and headset.consensus[ids[3]]["counts"]["uncertain"] == 1

    # Reclassifying a defect as its own type is refused before it is queued.
    with pytest.raises(ValueError, match="already is a gap"):
        headset.judge(ids[4], "reclassified", new_type="gap")
    assert headset.outbox == []

    # A judgment the server refuses (the device's clock is hours ahead) stops showing once
    # it has answered, and is kept in ``refused`` with the reason until cleared.
    shown = headset.judgment_of(ids[4], ines_id)
    headset.judge(ids[4], "reclassified", new_type="dent", at=now + timedelta(hours=2))
    assert headset.judgment_of(ids[4], ines_id)["verdict"] == "reclassified"
    pushed = headset.push()
    assert (
        pushed.results[0]["status"] == "rejected"
        and "set the device's clock" in pushed.results[0]["detail"]
    )
    assert headset.judgment_of(ids[4], ines_id) == shown and headset.outbox == []
    assert [(r["defect_id"], r["new_type"]) for r in headset.refused] == [(ids[4], "dent")]
    assert "ahead of the server's clock" in headset.refused[0]["reason"]
    assert len(headset.clear_refused()) == 1 and headset.refused == []


def test_sdk_covers_inspections_defects_feedback_and_errors(live):
    server, runtime, admin_token = live
    web = VistaClient(server.url)
    with pytest.raises(VistaError) as wrong:
        web.sign_in("ines", "nope")
    assert wrong.value.status == 401 and "password" in wrong.value.detail
    web.sign_in("ines", "ines-pw")
    created = web.create_inspection("wing", "component", aircraft="A320")
    assert web.inspection(created["id"])["aircraft"] == "A320"
    seed_defects(runtime, created["id"], 620)
    listed = list(web.defects(created["id"]))  # two pages of 500
    assert len(listed) == 620 and listed[-1]["location_mm"] == [619.0, 0.0, 0.0]
    gaps = list(web.defects(created["id"], type="gap"))
    assert len(gaps) == 155 and {d["type"] for d in gaps} == {"gap"}
    assert web.judge(listed[0]["id"], "confirmed")["consensus"]["total"] == 1
    assert web.feedback(created["id"])["inspection_id"] == created["id"]
    with pytest.raises(VistaError) as missing:
        web.inspection(10_000)
    assert missing.value.status == 404 and "10000" in missing.value.detail


def test_headset_outbox_sets_bad_items_aside_and_errors_are_one_line(live, tmp_path, capsys):
    from vista_client.headset import main

    server, runtime, admin_token = live
    admin = VistaClient(server.url, admin_token)
    inspection = admin.create_inspection("A320 cargo", "cargo")["id"]
    ids = seed_defects(runtime, inspection, 4)
    state = tmp_path / "headset.json"
    base = ["--url", server.url, "--token", admin_token, "--inspection", str(inspection)]

    # A mistyped verdict is refused before it is queued; the valid one after it is queued.
    assert main([*base, "--state", str(state)]) == 0  # a first sync, online
    typo = main(
        [
            *base,
            "--state",
            str(state),
            "--offline",
            "--judge",
            f"{ids[0]}=maybe",
            "--judge",
            f"{ids[1]}=confirmed",
        ]
    )
    assert typo == 2
    out, err = capsys.readouterr()
    assert f"queued: defect {ids[1]} confirmed" in out
    assert f"not queued: --judge {ids[0]}=maybe: defect {ids[0]}: verdict 'maybe'" in err
    saved = json.loads(state.read_text())
    assert [i["defect_id"] for i in saved["outbox"]] == [ids[1]]

    # An outbox written by an older client holds items the server refuses: they are set
    # aside with the reason, the others are applied, and nothing is stuck.
    stale = dict(saved["outbox"][0], client_id="old-1", defect_id=ids[2], verdict="maybe")
    naive = dict(
        saved["outbox"][0], client_id="old-2", defect_id=ids[3], client_time="2026-11-01T10:00:00"
    )  # no time zone: only the server knows
    saved["outbox"] += [stale, naive]
    state.write_text(json.dumps(saved))
    assert main([*base, "--state", str(state), "--judge", f"{ids[0]}=rejected"]) == 2
    out, err = capsys.readouterr()
    assert "pushed 2: {'applied': 2" in out and "refused 2" in out
    assert f"refused, kept in 'refused': defect {ids[2]} maybe: verdict 'maybe'" in err
    assert f"refused, kept in 'refused': defect {ids[3]} confirmed:" in err
    assert "time zone" in err and f"vista-headset refused --state {state}" in err
    saved = json.loads(state.read_text())
    assert saved["outbox"] == [] and len(saved["refused"]) == 2
    verdicts = {d: admin.judgments(d)["judgments"] for d in ids}
    assert [j["verdict"] for j in verdicts[ids[0]]] == ["rejected"]
    assert [j["verdict"] for j in verdicts[ids[1]]] == ["confirmed"]
    assert verdicts[ids[2]] == verdicts[ids[3]] == []

    # The server's refusals are one line each, never a traceback.
    for args, status in (
        (["--url", server.url, "--token", "vst_wrong", "--inspection", str(inspection)], 401),
        ([*base[:-1], "999"], 404),
    ):
        assert main(args) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"error: the server answered {status}: ") and err.count("\n") == 1


def test_headset_cli_never_loses_a_verdict(live, tmp_path, capsys):
    """Unreachable server: judgments queue in the state file and are sent later; without a
    state file there is no copy to judge from, which is said (exit 2); a refused judgment
    stays listed until cleared; a state file answers only for its inspection and server."""
    from vista_client.headset import main

    server, runtime, admin_token = live
    admin = VistaClient(server.url, admin_token)
    inspection = admin.create_inspection("A320 belly", "cargo")["id"]
    other = admin.create_inspection("A320 nose", "cargo")["id"]
    ids = seed_defects(runtime, inspection, 3)
    state = tmp_path / "headset.json"
    base = ["--token", admin_token, "--inspection", str(inspection), "--state", str(state)]
    online, unreachable = ["--url", server.url, *base], ["--url", "http://127.0.0.1:9", *base]

    assert main(online) == 0
    assert "scene first seen" in capsys.readouterr().out
    assert main(online) == 0
    assert "scene unchanged" in capsys.readouterr().out

    def copy_from(url: str) -> None:  # the state file as if synced from the server at url
        state.write_text(json.dumps(dict(json.loads(state.read_text()), url=url)))

    # No --offline, no server: the verdict and its comment wait in the state file.
    copy_from("http://127.0.0.1:9")
    assert main([*unreachable, "--judge", f"{ids[0]}=confirmed", "--comment", "burr"]) == 0
    out, err = capsys.readouterr()
    assert "server unreachable" in err
    assert f"queued: defect {ids[0]} confirmed ('burr')" in out
    assert f"1 judgment(s) wait in {state}" in out
    assert [i["comment"] for i in json.loads(state.read_text())["outbox"]] == ["burr"]
    # Without a state file there is no copy to judge from: said, and not a success.
    lost = main(["--url", "http://127.0.0.1:9", *base[:4], "--judge", f"{ids[1]}=rejected"])
    assert lost == 2
    assert (
        f"not queued: --judge {ids[1]}=rejected: defect {ids[1]} is not in"
        in capsys.readouterr().err
    )

    # Back online: the waiting verdict goes. Reclassifying as the same type is refused
    # locally; a judgment made on a clock far ahead, by the server.
    copy_from(server.url)
    gap = next(i for i in ids if admin.defect(i)["type"] == "gap")
    assert main([*online, "--judge", f"{gap}=reclassified:gap"]) == 2
    out, err = capsys.readouterr()
    assert "already is a gap" in err and "pushed 1: {'applied': 1" in out  # the queued one
    assert admin.judgments(ids[0])["judgments"][0]["comment"] == "burr"
    saved = json.loads(state.read_text())
    saved["outbox"] = [
        {
            "client_id": "ahead-1",
            "defect_id": ids[2],
            "inspection_id": inspection,
            "verdict": "confirmed",
            "comment": "",
            "client_time": (datetime.now(UTC) + timedelta(hours=3)).isoformat(),
        }
    ]
    state.write_text(json.dumps(saved))
    assert main(online) == 2
    assert "ahead of the server's clock" in capsys.readouterr().err
    assert main(online) == 0  # kept, never sent again
    assert "1 refused judgment(s) kept" in capsys.readouterr().err
    assert main(["refused", "--state", str(state)]) == 0
    assert f"defect {ids[2]} confirmed: client_time is" in capsys.readouterr().out
    assert main(["refused", "--state", str(state), "--clear-refused"]) == 0
    assert "cleared 1 refused judgment(s)" in capsys.readouterr().out
    assert json.loads(state.read_text())["refused"] == []

    # A state file answers only for its own inspection and server.
    assert main(["--url", server.url, *base[:2], "--inspection", str(other), *base[4:]]) == 2
    assert f"holds inspection {inspection}, not {other}" in capsys.readouterr().err
    assert main(["--url", server.url + "/", *base]) == 0  # the same server, spelt with a slash
    capsys.readouterr()
    assert main(["--url", "http://localhost:1", *base]) == 2
    assert "holds a copy from" in capsys.readouterr().err
