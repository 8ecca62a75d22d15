"""Measuring again keeps the judgments: a new measurement's findings continue the last
one's (matched by seam and place, or by overlap and type), carrying judgments with their
history; what it did not find again ends; every count sees each physical defect once; a
headset's verdict queued offline across the re-measure lands on the successor."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from vista_client import Headset, VistaClient

from contract.context import NewDefect
from supervisor.defects.lineage import Placed, match, pieces
from tests.conftest import add_user
from tests.seeding import record_measurement

SEAM = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]])


def _placed(id_: int, kind: str, at, extent=2.0, seam=None) -> Placed:
    return Placed(id_, kind, np.asarray(at, float), extent, seam)


def test_a_seams_finding_matches_on_the_same_seam_only() -> None:
    moved = SEAM + [0.0, 0.3, 0.0]  # the same seam, measured again
    old = [
        _placed(1, "gap", [40, 0, 0], 10, SEAM),
        _placed(2, "gap", [40, 12, 0], 10, SEAM + [0, 12, 0]),  # the next seam over
        _placed(3, "step", [40, 0, 0], 10, SEAM),
    ]
    new = [_placed(11, "gap", [55, 0.3, 0], 10, moved)]  # its worst place moved 15 mm
    assert match(old, new) == {11: 1}
    across = SEAM[:, [1, 0, 2]]  # a seam at right angles through the same point
    assert match(old, [_placed(12, "gap", [40, 0, 0], 10, across)]) == {}
    far_along = [_placed(13, "gap", [95, 0, 0], 2, moved)]  # 55 mm away: another place
    assert match([_placed(1, "gap", [40, 0, 0], 2, SEAM)], far_along) == {}


def test_surface_findings_match_by_overlap_and_type_and_pieces_join() -> None:
    old = [
        _placed(1, "dent", [0, 0, 0], 10),
        _placed(2, "scratch", [50, 0, 0], 20),
        _placed(3, "scratch", [68, 0, 0], 10),  # the same scratch, found in two pieces
        _placed(4, "bump", [200, 0, 0], 4),
    ]
    new = [
        _placed(11, "dent", [1.5, 0, 0], 10),
        _placed(12, "scratch", [56, 0, 0], 36),
        _placed(13, "dent", [200, 0, 0], 4),  # not a bump
    ]
    matched = match(old, new)
    assert matched == {11: 1, 12: 2}
    assert pieces(old, new, matched) == {3: 12}


@pytest.fixture(scope="module")
def two_measurements() -> list[tuple[list[NewDefect], list]]:
    """One simulated assembly scanned twice every 0.2 mm (noise seeds 10 and 11) and
    measured each time as the job does: its findings and its cloud's bounds."""
    from services.defects.config import MeasureConfig
    from services.defects.example import BASE_T_PART, merged_cloud
    from services.defects.jobs import _in_tolerance_seams, _new_defect
    from services.defects.measure import measure
    from services.defects.run import _bounds_mm
    from services.defects.simulate import AssemblySpec, SensorModel, random_assembly, scan_assembly

    assembly = random_assembly(AssemblySpec(), np.random.default_rng(3))
    measured = []
    for noise_seed in (10, 11):
        scans = scan_assembly(
            assembly,
            BASE_T_PART,
            SensorModel(grid=(500, 770)),
            rng=np.random.default_rng(noise_seed),
        )
        cloud = merged_cloud(scans, 0.1)
        result = measure(cloud, MeasureConfig(), threads=2)
        found = [_new_defect(f) for f in result.defects + result.uncertain]
        measured.append((found + _in_tolerance_seams(result), _bounds_mm(cloud.points)))
    return measured


@pytest.fixture
def live(live_api):
    _, runtime, _ = live_api
    add_user(runtime, "ines", "inspector", "ines-pw")
    return live_api


def _by_type(defects: list[dict], kind: str) -> list[dict]:
    return [d for d in defects if d["type"] == kind]


def test_measuring_again_carries_judgments_and_counts_each_defect_once(
    live, two_measurements
) -> None:
    server, runtime, admin_token = live
    admin = VistaClient(server.url, admin_token)
    ines_id = next(u["id"] for u in admin.users() if u["username"] == "ines")
    web = VistaClient(server.url)
    web.sign_in("ines", "ines-pw")
    inspection = web.create_inspection("wing panel 7", "component")["id"]
    (first, first_bounds), (second, second_bounds) = two_measurements
    reflection = NewDefect(  # a glint the first scan took for a scratch
        type="scratch",
        location_mm=tuple(np.mean(first_bounds, axis=0)),
        normal=(0.0, 0.0, 1.0),
        value_mm=0.2,
        tolerance_mm=0.1,
        extent_mm=4.0,
        severity="minor",
        confidence=0.5,
    )
    run_1, _ = record_measurement(runtime, inspection, [*first, reflection], bounds_mm=first_bounds)
    listed = list(web.defects(inspection))
    assert len(listed) == len(first) + 1
    dents = _by_type(listed, "dent")
    confirmed, dismissed = dents[0], dents[1]
    web.judge(confirmed["id"], "confirmed", comment="felt it")
    web.judge(confirmed["id"], "confirmed", comment="felt it, 0.3 mm deep")
    web.set_status(dismissed["id"], "dismissed", reason="tooling mark, not a dent")
    glint = next(d for d in listed if d["confidence"] == 0.5)

    device = admin.create_token(ines_id, "hololens-2", kind="device")
    headset = Headset(VistaClient(server.url, device), inspection)
    headset.sync()
    headset.go_offline()  # the headset judges while the part is measured again
    later = datetime.now(UTC) - timedelta(seconds=5)
    bump = _by_type(listed, "bump")[0]
    headset.judge(bump["id"], "rejected", comment="paint run", at=later)
    headset.judge(glint["id"], "confirmed", at=later)

    run_2, _ = record_measurement(runtime, inspection, second, bounds_mm=second_bounds)
    current = list(web.defects(inspection))
    assert {d["run_id"] for d in current} == {run_2} and len(current) == len(second)
    every = list(web.defects(inspection, history=True))
    ended = [d for d in every if d["run_id"] == run_1]
    assert all(d["ended"] for d in ended)
    superseded = [d for d in ended if d["ended"] == "superseded"]
    assert len(superseded) >= len(first) - 1  # each physical defect found again
    assert next(d for d in ended if d["id"] == glint["id"])["ended"] == "not found again"

    successor = next(d for d in current if d["supersedes_id"] == confirmed["id"])
    assert successor["consensus"]["counts"]["confirmed"] == 1
    judgments = web.judgments(successor["id"])["judgments"]
    mine = next(j for j in judgments if j["username"] == "ines")
    assert (mine["revision"], mine["judged_on_run_id"]) == (2, run_1)
    assert [h["comment"] for h in mine["history"]] == ["felt it", "felt it, 0.3 mm deep"]
    still = next(d for d in current if d["supersedes_id"] == dismissed["id"])
    assert still["status"] == "dismissed" and still["status_reason"] == "tooling mark, not a dent"
    history = web.defect_history(successor["id"])
    assert [s["run_id"] for s in history["steps"]] == [run_1, run_2]
    assert history["current_id"] == successor["id"]
    assert [(j["revision"], j["judged_on_run_id"]) for j in history["judgments"]] == [
        (1, run_1),
        (2, run_1),
    ]

    # Feedback sees each physical defect once: the dents it counts are the current ones.
    feedback = web.feedback(inspection, min_reviews=1)
    counted = sum(
        g["flagged"] + g["in_tolerance"] for g in feedback["groups"] if g["type"] == "dent"
    )
    assert counted == len(_by_type(current, "dent"))

    # The sync sends a finding's lineage with it once it has one, all of it.
    from supervisor.sync.schemas import SyncDefect

    page = web.sync(inspection)
    carried = next(d for d in page["defects"] if d["id"] == successor["id"])
    SyncDefect.model_validate(carried)
    assert set(carried) == set(SyncDefect.model_fields) - {"notes"}
    assert carried["lineage_id"] == confirmed["id"]

    # The headset: the first run's findings leave its list, the queued verdicts land on
    # the successor or come back refused with the reason.
    headset.go_online()
    pulled = headset.sync()
    assert pulled.ended == len(first) + 1
    assert set(headset.defects) == {d["id"] for d in current}
    bump_now = headset.successor_of(bump["id"])
    assert headset.judgment_of(bump_now, ines_id)["comment"] == "paint run"
    pushed = headset.push()
    by_defect = {r["defect_id"]: r for r in pushed.results}
    assert by_defect[bump["id"]]["status"] == "applied"
    assert by_defect[bump["id"]]["landed_on"] == bump_now
    assert "landed on its successor" in by_defect[bump["id"]]["detail"]
    assert by_defect[glint["id"]]["status"] == "rejected"
    assert "not found again" in by_defect[glint["id"]]["detail"]
    assert [r["defect_id"] for r in headset.refused] == [glint["id"]]
    landed = next(j for j in web.judgments(bump_now)["judgments"] if j["username"] == "ines")
    assert (landed["verdict"], landed["judged_on_run_id"]) == ("rejected", run_1)
    headset.sync()
    assert headset.judgments[(bump_now, ines_id)]["comment"] == "paint run"
