"""The Unity/HoloLens reference client (clients/unity): its protocol core compiles with Mono's
C# compiler without warnings and, run against a live supervisor, signs in, syncs in pages,
reads the scene, aligns on a marker and pushes offline judgments (applied, retried, stale,
an answer lost and replayed after a restart from saved state, in batches, rejected and kept
until cleared)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import httpx
import pytest

from supervisor.engine.runtime import Runtime
from supervisor.records import DomainRecords
from tests.conftest import add_user, auth, make_settings
from tests.seeding import seed_defects, seed_warning

UNITY = Path(__file__).resolve().parent.parent / "clients" / "unity"
CORE = UNITY / "Runtime" / "Core"
SMOKE = UNITY / "Tests" / "ProtocolSmoke.cs"
NO_MONO = (
    "Mono's C# compiler is missing: run `make install-test` (it installs Debian's mono-mcs "
    "and libmono-system-net-http4.0-cil)"
)
DEFECTS = 7
WARNING = "2 of 4 seams unmeasured, so their gap, parallelism and mismatch are not judged"
COMMENT = 'Spalt größer als 1 mm – "gut sichtbar"\n\N{EYES}'  # as ProtocolSmoke.cs writes it
MARKER = {
    "name": "cabin-left",
    "area": "cabin",
    "base_T_marker": [[0, -1, 0, 1200.5], [1, 0, 0, -340.25], [0, 0, 1, 95.0], [0, 0, 0, 1]],
    "size_mm": 210.0,
    "image": "vista-cabin",
}


@pytest.fixture(scope="module")
def smoke_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The protocol core and its smoke test, compiled with warnings as errors."""
    mcs, mono = shutil.which("mcs"), shutil.which("mono")
    if not (mcs and mono):
        pytest.fail(NO_MONO)
    out = tmp_path_factory.mktemp("unity") / "smoke.exe"
    sources = [str(p) for p in sorted(CORE.glob("*.cs"))] + [str(SMOKE)]
    done = subprocess.run(
        [mcs, "-target:exe", f"-out:{out}", "-r:System.Net.Http.dll", "-warnaserror", *sources],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, f"mcs failed:\n{done.stdout}{done.stderr}"
    return out


def test_core_is_plain_csharp_and_the_package_is_well_formed():
    sources = sorted(CORE.glob("*.cs"))
    assert sources
    for source in sources:
        assert "UnityEngine" not in source.read_text(encoding="utf-8"), source.name
    package = json.loads((UNITY / "package.json").read_text(encoding="utf-8"))
    assert package["name"] == "com.vista.client" and package["version"] == "1.0.0"
    assert "com.unity.cloud.gltfast" in package["dependencies"]
    core = json.loads((CORE / "Vista.Client.Core.asmdef").read_text(encoding="utf-8"))
    assert core["noEngineReferences"] is True
    glue = json.loads((UNITY / "Runtime" / "Unity" / "Vista.Client.Unity.asmdef").read_text())
    assert {"Vista.Client.Core", "glTFast"} <= set(glue["references"])


def test_protocol_core_against_a_live_supervisor(smoke_exe, start_server, sqlite_url, tmp_path):
    settings = make_settings(tmp_path, sqlite_url)
    runtime = Runtime.create(settings, records=DomainRecords())
    try:
        token = add_user(runtime, "ines", "inspector", "pw")
        server = start_server(settings, run_engine=False)
        created = httpx.post(
            f"{server.url}/api/v1/inspections",
            json={"title": "sidewall", "area": "cabin", "markers": [MARKER]},
            headers=auth(token),
            timeout=10,
        )
        assert created.status_code == 201, created.text
        inspection = created.json()["id"]
        ids = seed_defects(runtime, inspection, DEFECTS, uncertain=(6,))
        warned = seed_warning(runtime, inspection, WARNING, 2)
    finally:
        runtime.db.dispose()

    done = subprocess.run(
        ["mono", str(smoke_exe), server.url, "ines", "pw", str(inspection)],
        capture_output=True,
        encoding="utf-8",
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["signed_in"] is True and summary["inspection_listed"] is True
    assert "password" in summary["problem_detail"]
    assert summary["defects"] == summary["scene_defect_nodes"] == DEFECTS
    assert summary["sync_pages"] == 3  # 7 defects in pages of 3
    # a measurement that left seams unmeasured, and a finding within 2σ of its limit, as the
    # headset reads them — and keeps them through a restart
    assert summary["warnings"] == [{"job_id": warned, "warning": WARNING, "unmeasured_seams": 2}]
    assert summary["warnings_restored"] is True
    assert summary["uncertain_defects"] == [ids[6]]
    assert summary["scene_not_modified"] is True
    assert summary["scene_changed"] is False  # a judgment travels in the sync, not the scene
    assert summary["anchors"] == 1
    assert summary["anchor_error"] < 1e-6 and summary["alignment_error"] < 1e-9
    assert summary["json_cases"] > 10
    assert summary["defect_id"] == ids[0] and summary["verdict"] == "confirmed"
    assert summary["comment"] == COMMENT  # sent as UTF-8, read back from \u escapes
    assert summary["pushed"] == "applied" and summary["replayed"] is True
    assert summary["consensus_total"] == summary["consensus_confirmed"] == 1
    assert summary["stale_replaced"] is True
    assert summary["state_restored"] is True and summary["lost_answer_replayed"] is True
    assert summary["push_requests"] == 2  # 3 items in batches of 2
    assert "ahead of the server's clock" in summary["rejected_detail"]
    assert summary["refused_kept"] is True
    lines = summary["list_lines"]  # seeding.py: defect i is a gap/step/scratch/dent of 1 + i/100 mm
    assert lines[0] == "gap 1.00 mm = 1.00 mm · resolved · 1/1 confirmed"
    assert lines[1] == "step 1.01 mm > 1.00 mm · open · 1/1 rejected"
    assert lines[3] == "dent 1.03 mm > 1.00 mm · open · not judged"
    assert lines[4] == "gap 1.04 mm > 1.00 mm · open · 1/1 uncertain, needs review"

    def judgments(defect_id: int) -> dict:
        answer = httpx.get(
            f"{server.url}/api/v1/defects/{defect_id}/judgments", headers=auth(token), timeout=10
        )
        assert answer.status_code == 200, answer.text
        return answer.json()

    expected = {
        ids[0]: ("confirmed", COMMENT),
        ids[1]: ("rejected", "newer"),
        ids[2]: ("confirmed", ""),
        ids[4]: ("uncertain", "cannot see it from here"),
        ids[5]: ("confirmed", ""),
    }
    for defect_id, (verdict, comment) in expected.items():
        state = judgments(defect_id)
        [mine] = state["judgments"]
        assert (mine["username"], mine["verdict"], mine["comment"]) == ("ines", verdict, comment)
        assert [h["revision"] for h in mine["history"]] == [1]  # retries changed nothing
        assert state["consensus"]["total"] == 1
    assert judgments(ids[3])["judgments"] == judgments(ids[6])["judgments"] == []


def test_a_verdict_queued_across_a_re_measure_lands_on_the_successor(
    start_server, sqlite_url, tmp_path
):
    """LineageSmoke.cs: the headset judges a dent offline; the part is measured again
    meanwhile (the dent found 1 mm away, the scratch not at all); after the sync the dent's
    first finding has left the list, its successor shows the queued verdict, the push lands
    it there marked as judged on the first run, and a restart keeps the history apart."""
    from contract.context import NewDefect
    from tests.seeding import record_measurement

    mcs, mono = shutil.which("mcs"), shutil.which("mono")
    if not (mcs and mono):
        pytest.fail(NO_MONO)
    exe = tmp_path / "lineage.exe"
    sources = [str(p) for p in sorted(CORE.glob("*.cs"))] + [
        str(UNITY / "Tests" / "LineageSmoke.cs")
    ]
    built = subprocess.run(
        [mcs, "-target:exe", f"-out:{exe}", "-r:System.Net.Http.dll", "-warnaserror", *sources],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert built.returncode == 0, f"mcs failed:\n{built.stdout}{built.stderr}"

    def finding(kind: str, x_mm: float) -> NewDefect:
        return NewDefect(kind, (x_mm, 0.0, 0.0), (0.0, 0.0, 1.0), 0.4, 0.2, 6.0, "major", 0.9)

    bounds = [[-50.0, -50.0, -5.0], [150.0, 50.0, 5.0]]
    settings = make_settings(tmp_path, sqlite_url)
    runtime = Runtime.create(settings, records=DomainRecords())
    try:
        token = add_user(runtime, "ines", "inspector", "pw")
        server = start_server(settings, run_engine=False)
        inspection = httpx.post(
            f"{server.url}/api/v1/inspections",
            json={"title": "wing panel", "area": "component"},
            headers=auth(token),
            timeout=10,
        ).json()["id"]
        first_run, _ = record_measurement(
            runtime, inspection, [finding("dent", 0.0), finding("scratch", 80.0)], bounds_mm=bounds
        )
        dent = httpx.get(
            f"{server.url}/api/v1/defects",
            params={"inspection": inspection, "type": "dent"},
            headers=auth(token),
            timeout=10,
        ).json()["items"][0]["id"]
        smoke = subprocess.Popen(
            ["mono", str(exe), server.url, "ines", "pw", str(inspection), str(dent)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            encoding="utf-8",
        )
        try:
            assert smoke.stdout.readline().strip() == "queued", smoke.stderr.read()
            record_measurement(runtime, inspection, [finding("dent", 1.0)], bounds_mm=bounds)
            out, err = smoke.communicate("measured\n", timeout=60)
        finally:
            smoke.kill()
    finally:
        runtime.db.dispose()
    assert smoke.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["before"], summary["after"], summary["ended"]) == (2, 1, 2)
    assert summary["judged_still_listed"] is False and summary["successor"] != dent
    assert summary["shown_on_successor"] == "rejected"
    [pushed] = summary["pushed"]
    assert (pushed["defect_id"], pushed["status"]) == (dent, "applied")
    assert pushed["landed_on"] == summary["successor"]
    assert "landed on its successor" in pushed["detail"]
    assert summary["stored_verdict"] == "rejected" and summary["stored_revision"] == 1
    assert summary["judged_on_run"] == first_run
    assert (summary["restored_current"], summary["restored_ended"]) == (1, 2)
