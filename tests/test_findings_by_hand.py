"""Findings by hand and notes: an inspector reports a finding with a note, anyone who
edits annotates any finding; both reach a headset with the sync and the audit log."""

from __future__ import annotations

import pytest
from vista_client import Headset, VistaClient

from tests.conftest import add_user
from tests.seeding import seed_defects


@pytest.fixture
def live(live_api):
    _, runtime, _ = live_api
    add_user(runtime, "ines", "inspector", "ines-pw")
    add_user(runtime, "vic", "viewer", "vic-pw")
    return live_api


def test_a_finding_by_hand_and_notes_reach_the_headset_and_the_audit_log(live) -> None:
    server, runtime, admin_token = live
    admin = VistaClient(server.url, admin_token)
    ines = VistaClient(server.url)
    ines.sign_in("ines", "ines-pw")
    inspection = ines.create_inspection("wing flap 3", "wing, left outer flap")["id"]
    assert ines.inspection(inspection)["area"] == "wing, left outer flap"  # free text
    measured = seed_defects(runtime, inspection, 1)[0]
    device = admin.create_token(
        next(u["id"] for u in admin.users() if u["username"] == "ines"), "hl-2", kind="device"
    )
    headset = Headset(VistaClient(server.url, device), inspection)
    headset.sync()
    assert "notes" not in headset.defects[measured]  # none: not sent

    reported = ines.report_defect(
        inspection,
        "dent",
        [120.0, 40.5, 3.2],
        severity="major",
        value_mm=0.35,
        note="felt with the hand near rivet row 4",
    )
    assert reported["source"] == "manual" and reported["value_mm"] == 0.35
    assert [n["text"] for n in reported["notes"]] == ["felt with the hand near rivet row 4"]
    noted = ines.annotate(measured, "paint drip, not a dent?")
    assert noted["notes"][0]["username"] == "ines"
    with pytest.raises(Exception, match="403"):
        viewer = VistaClient(server.url)
        viewer.sign_in("vic", "vic-pw")
        viewer.annotate(measured, "a viewer's note")
    pulled = headset.sync()
    assert pulled.defects == 2
    assert headset.defects[reported["id"]]["notes"][0]["text"].startswith("felt with the hand")
    assert headset.defects[measured]["notes"][0]["text"] == "paint drip, not a dent?"
    actions = {
        (e["action"], e["entity_id"])
        for e in admin.request("GET", "/audit", params={"inspection": inspection}).json()["items"]
    }
    assert ("report", reported["id"]) in actions and ("annotate", measured) in actions
    areas = ines.request("GET", "/areas").json()
    assert areas[0] == "wing, left outer flap" and "cabin" in areas
