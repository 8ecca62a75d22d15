"""The dashboard does the job end to end, in Debian's Chromium at 1024 px: an inspector
creates an inspection, uploads a scanner's E57 (progress, conversion named) and a file that
is no cloud (refused beside its name), starts a measure run from the job kind's own form,
watches it finish and judges a finding twice (the history shows both); a queued job is
cancelled and retried from its row."""

from __future__ import annotations

import httpx
import pytest

from benches.browser import launch_chromium
from tests.conftest import add_user, auth, make_settings, wait_for
from tests.edgeclouds import seam_cloud
from tests.seeding import measure_uploaded


def _sign_in(page, url: str) -> None:
    page.goto(url + "/")
    page.fill("input[name=username]", "ines")
    page.fill("input[name=password]", "ines-pw")
    page.click("#sign-in-form button")
    page.wait_for_selector("#view-inspections:not([hidden])")


def _seam_e57(path) -> None:
    """A 4 mm gap between two panels (the default limit is 3 mm), as an E57 in metres."""
    import pye57

    points = seam_cloud(4.0, 0.0, ("square", 0.0), ("square", 0.0), spacing_mm=0.25).points
    e57 = pye57.E57(str(path), mode="w")
    e57.write_scan_raw({f"cartesian{a}": points[:, i] / 1000.0 for i, a in enumerate("XYZ")})
    e57.close()


@pytest.fixture
def browser():
    with launch_chromium() as chromium:
        yield chromium


def test_create_upload_measure_and_judge_from_the_browser(
    start_server, tmp_path, sqlite_url, browser
):
    settings = make_settings(tmp_path, sqlite_url, embedded_workers=1, extra_job_kinds=[])
    server = start_server(settings)
    runtime = server.runtime
    add_user(runtime, "ines", "inspector", "ines-pw")
    scan = tmp_path / "wing-seam.e57"
    _seam_e57(scan)
    notes = tmp_path / "notes.txt"
    notes.write_text("gap looks wide near the hinge\n")

    page = browser.new_page(viewport={"width": 1024, "height": 768})
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    _sign_in(page, server.url)
    page.click("#new-inspection summary")
    page.fill("#new-inspection-form input[name=title]", "wing seam")
    page.fill("#new-inspection-form input[name=aircraft]", "A320 MSN 1234")
    page.fill("#new-inspection-area", "wing, left outer flap")  # free text
    page.click("#new-inspection-form button")
    page.wait_for_selector("#view-inspection:not([hidden])")
    inspection = int(page.evaluate("location.hash").split("/")[2])

    page.click("[role=tab][data-tab=files]")
    page.set_input_files("#upload-file", [str(scan), str(notes)])
    page.click("#upload-form button")
    page.wait_for_selector("#uploads li[data-name='wing-seam.e57'].done", timeout=60_000)
    page.wait_for_selector("#uploads li[data-name='notes.txt'].refused")
    kept = page.text_content("#uploads li[data-name='wing-seam.e57']")
    assert "kept as wing-seam.ply (cloud, from E57 in m (its convention))" in kept, kept
    refused = page.text_content("#uploads li[data-name='notes.txt']")
    assert "notes.txt (kind=cloud)" in refused and "nor is it a PCD" in refused, refused
    bar = "#uploads li[data-name='wing-seam.e57'] progress"
    assert page.eval_on_selector(bar, "bar => bar.value") == 1
    page.wait_for_selector("#artifact-table tbody tr")
    assert page.locator("#artifact-table tbody tr").count() == 1  # nothing kept of the refusal

    page.click("[role=tab][data-tab=timeline]")
    page.click("#run-box summary")
    assert page.input_value("#run-kind") == "defects.measure"
    assert "wing-seam.ply" in page.text_content("#run-inputs select")
    page.click("#run-form details.params summary")  # the parameters fold out
    pitch = "#run-params [data-param=pitch_mm]"
    page.fill(pitch, "500")  # over the schema's maximum: the form itself refuses
    assert page.eval_on_selector(pitch, "field => field.validity.rangeOverflow")
    page.fill(pitch, "4")
    page.fill("#run-params [data-param=max_gap_mm]", "0")  # must be over 0: the server says so
    page.click("#run-form button[type=submit]")
    page.wait_for_selector("#run-error:has-text('max_gap_mm')")
    assert "greater than 0" in page.text_content("#run-error"), page.text_content("#run-error")
    page.fill("#run-params [data-param=max_gap_mm]", "")
    page.fill("#run-name", "first look")
    page.click("#run-form button[type=submit]")
    page.wait_for_selector("#timeline .run-head:has-text('first look')")
    page.wait_for_selector("#timeline .job .status-succeeded", timeout=120_000)
    run = httpx.get(
        f"{server.url}/api/v1/inspections/{inspection}/runs",
        headers=auth(_token(server.url)),
        timeout=10,
    ).json()["items"][0]
    assert run["jobs"][0]["params"]["pitch_mm"] == 4  # only what was changed was sent

    # The measurement's own page: its seams in a table, a cross-section at any section
    # along each, its 3D scene.
    job = run["jobs"][0]["id"]
    page.click(f"#timeline .job[data-job='{job}'] a.job-step")
    page.wait_for_selector(".panel-table[data-title='Seams'] tbody tr")
    assert page.locator(".panel-table[data-title='Seams'] tbody tr").count() == 1
    assert "P0–P1" in page.text_content(".panel-table[data-title='Seams'] tbody tr")
    page.wait_for_selector("#section-values")
    first_at = page.text_content("#section-where")
    assert "gap" in page.text_content("#section-values")
    assert page.locator(".section-plot circle").count() > 20  # the cloud's points across it
    page.locator("#section-along").fill("3")
    assert page.text_content("#section-where") != first_at
    page.wait_for_selector("#scene-note:has-text('drag to turn')")
    page.screenshot(path=str(tmp_path / "measure-page-1024.png"), full_page=True)
    page.go_back()

    page.click("[role=tab][data-tab=defects]")
    page.wait_for_selector("#defect-list .row", timeout=30_000)
    page.wait_for_selector("#scene-status:has-text('2 panels')", timeout=30_000)
    page.click("#defect-list .row >> nth=0")
    page.wait_for_selector("#detail:not([hidden])")
    assert "limits0.50–3.00 mm" in page.text_content("#detail-facts")  # the defaults' range
    page.click(".verdicts button[data-verdict=uncertain]")
    page.wait_for_selector("#judgments li[data-user=ines]:has-text('uncertain')")
    page.fill("#comment", "measured again with a gauge: 4.1 mm")
    page.click(".verdicts button[data-verdict=confirmed]")
    page.wait_for_selector("#judgments li[data-user=ines] .history summary:has-text('2 revisions')")
    page.click("#judgments li[data-user=ines] .history summary")
    revisions = page.locator("#judgments li[data-user=ines] .history li").all_text_contents()
    assert revisions[0].startswith("confirmed — measured again with a gauge")
    assert revisions[1].startswith("uncertain")
    history = "#judgments li[data-user=ines] .history[open]"

    # A finding measured before vista kept a gap's range turns stale when the tolerances
    # change: one click measures its cloud again, as its run did.
    from supervisor.models import Defect

    finding = int(page.get_attribute("#defect-list .row >> nth=0", "data-id"))
    with runtime.db.session(write=True) as session:
        defect = session.get(Defect, finding)
        defect.measurements = {
            k: v for k, v in defect.measurements.items() if not k.startswith("gap_range")
        }
        session.commit()
    http = httpx.Client(base_url=server.url, headers=auth(_token(server.url)), timeout=10)
    changed = http.patch(
        f"/api/v1/inspections/{inspection}", json={"tolerances": {"gap_mm": {"max": 6.0}}}
    )
    assert changed.status_code == 200, changed.text
    page.wait_for_selector("#detail-facts #remeasure", timeout=15_000)
    assert page.locator(history).count() == 1  # the pane drawn again: the history kept, open
    assert "re-run the measurement" in page.text_content("#detail-facts")
    page.click("#remeasure")
    page.wait_for_selector("#timeline .run-head:has-text('measure again (run 1)')")
    again = http.get(f"/api/v1/inspections/{inspection}/runs").json()["items"][0]["jobs"][0]
    assert again["params"]["pitch_mm"] == 4 and again["kind"] == "defects.measure"
    http.close()
    assert errors == []


def _token(url: str) -> str:
    answer = httpx.post(
        f"{url}/api/v1/auth/token", json={"username": "ines", "password": "ines-pw"}, timeout=10
    )
    return answer.json()["access_token"]


def test_cancel_and_retry_a_job_from_its_row(start_server, tmp_path, sqlite_url, browser):
    """No engine runs here, so the job waits in the queue until the buttons move it."""
    from services.lib.pointcloud.ply import write_ply

    settings = make_settings(tmp_path, sqlite_url)
    server = start_server(settings, run_engine=False)
    runtime = server.runtime
    add_user(runtime, "ines", "inspector", "ines-pw")
    add_user(runtime, "vic", "viewer", "vic-pw")
    http = httpx.Client(base_url=server.url, headers=auth(_token(server.url)), timeout=10)
    inspection = http.post("/api/v1/inspections", json={"title": "t", "area": "cabin"}).json()["id"]
    cloud = tmp_path / "c.ply"
    write_ply(cloud, seam_cloud(4.0, 0.0, ("square", 0.0), ("square", 0.0), spacing_mm=1.0))
    job = measure_uploaded(http, inspection, cloud)["jobs"][0]["id"]

    page = browser.new_page(viewport={"width": 1440, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    _sign_in(page, server.url)
    page.goto(f"{server.url}/#/inspections/{inspection}")
    page.click("[role=tab][data-tab=timeline]")
    row = f"#timeline .job[data-job='{job}']"
    page.click(f"{row} button[data-action=cancel]")
    page.wait_for_selector(f"{row} .status-cancelled")
    page.click(f"{row} button[data-action=retry]")
    page.wait_for_selector(f"{row} .status-queued")
    assert page.locator(f"{row} button[data-action=cancel]").count() == 1
    assert http.get(f"/api/v1/jobs/{job}").json()["status"] == "queued"

    # A viewer sees the runs but no buttons and no forms.
    page.click("#sign-out")
    page.fill("input[name=username]", "vic")
    page.fill("input[name=password]", "vic-pw")
    page.click("#sign-in-form button")
    page.wait_for_selector("#view-inspections:not([hidden])")
    assert page.locator("#new-inspection").is_hidden()
    page.goto(f"{server.url}/#/inspections/{inspection}")
    page.click("[role=tab][data-tab=timeline]")
    page.wait_for_selector(f"{row} .status-queued")
    assert page.locator(f"{row} button").count() == 0 and page.locator("#run-box").is_hidden()
    http.close()
    assert errors == [], errors


def test_unmeasured_seams_and_uncertain_findings_show_as_such(
    start_server, tmp_path, sqlite_url, browser
):
    """A measurement whose one seam no edge model explains: the inspection's status reads
    "1 seam unmeasured" (not a plain status), the defects tab says which seam and why, the
    run's job reads "succeeded · warning", and the scene draws the seam as unmeasured. A
    finding within 2σ of its limit is listed as uncertain, filtered as such, with its σ
    and the advice in its details."""
    from services.lib.pointcloud.ply import write_ply
    from supervisor.models import Defect

    settings = make_settings(tmp_path, sqlite_url, embedded_workers=1, extra_job_kinds=[])
    server = start_server(settings)
    runtime = server.runtime
    add_user(runtime, "ines", "inspector", "ines-pw")
    http = httpx.Client(base_url=server.url, headers=auth(_token(server.url)), timeout=10)
    inspection = http.post("/api/v1/inspections", json={"title": "t", "area": "cabin"}).json()["id"]
    cloud = tmp_path / "rebate.ply"
    write_ply(cloud, seam_cloud(2.0, 0.0, ("rebate", 1.0), ("square", 0.0), spacing_mm=0.25))
    run = measure_uploaded(http, inspection, cloud)
    job = run["jobs"][0]["id"]
    with runtime.db.write() as session:
        unsure = Defect(
            inspection_id=inspection, run_id=run["id"], job_id=job, type="step", value_mm=0.52,
            tolerance_mm=0.5, severity="minor", source="job", location_mm=[0.0, 50.0, 0.0],
            normal=[0.0, 0.0, 1.0], confidence=0.65,
            measurements={"value": 0.52, "unit": "mm", "tolerance": 0.5, "sigma_mm": 0.03,
                          "tolerance_state": "uncertain", "advice": "re-scan at ≤ 0.08 mm spacing"},
        )  # fmt: skip
        session.add(unsure)
        session.flush()
        unsure_id = unsure.id

    page = browser.new_page(viewport={"width": 1440, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    _sign_in(page, server.url)
    page.goto(f"{server.url}/#/inspections/{inspection}")
    page.wait_for_selector("#inspection-status:has-text('1 seam unmeasured')", timeout=120_000)
    assert page.locator("#inspection-status.status-warning").count() == 1
    banner = page.text_content("#run-warning")
    assert "seam 0 (P0–P1)" in banner and "fits no model" in banner, banner
    row = f"#defect-list .row[data-id='{unsure_id}']"
    assert page.text_content(f"{row} .severity-uncertain") == "uncertain"
    page.select_option("#filter-severity", "uncertain")
    assert page.locator("#defect-list .row").count() == 1
    page.select_option("#filter-severity", "out")
    assert page.locator(row).count() == 0
    page.select_option("#filter-severity", "")
    page.click(row)
    page.wait_for_selector("#detail:not([hidden])")
    facts = page.text_content("#detail-facts")
    assert "± 0.030 mm (1σ)" in facts and "re-scan at ≤ 0.08 mm spacing" in facts, facts
    assert "uncertain" in page.text_content("#detail-title")
    page.wait_for_selector("#legend:has-text('unmeasured seam')")
    page.click("[role=tab][data-tab=timeline]")
    status = f"#timeline .job[data-job='{job}'] .status-warning"
    page.wait_for_selector(status)
    assert page.text_content(status) == "succeeded · warning"
    http.close()
    assert errors == [], errors


def test_tolerances_edited_in_the_browser_keep_the_limits_not_touched(
    start_server, tmp_path, sqlite_url, browser
):
    """The Tolerances tab: a form drawn from the schema with the defaults shown; changing
    the gap's maximum keeps the surface limits; emptying a limit restores its default; a
    named set is applied, its name and version shown; another inspector reads, not edits."""
    settings = make_settings(tmp_path, sqlite_url)
    server = start_server(settings, run_engine=False)
    runtime = server.runtime
    add_user(runtime, "ines", "inspector", "ines-pw")
    ivan = add_user(runtime, "ivan", "inspector", "ivan-pw")
    http = httpx.Client(base_url=server.url, headers=auth(_token(server.url)), timeout=10)
    surface = {"dent_depth_mm": 0.5, "scratch_depth_mm": 0.3}
    inspection = http.post(
        "/api/v1/inspections",
        json={"title": "lining", "area": "cabin", "tolerances": {"surface": surface}},
    ).json()["id"]
    lining = httpx.post(
        f"{server.url}/api/v1/tolerance-sets",
        json={"name": "A320 lining", "tolerances": {"step_mm": {"max": 0.8}}},
        headers=auth(ivan),
        timeout=10,
    ).json()

    for width, height in ((1440, 900), (1024, 768)):
        page = browser.new_page(viewport={"width": width, "height": height})
        errors: list[str] = []
        page.on("pageerror", lambda error, errors=errors: errors.append(str(error)))
        _sign_in(page, server.url)
        page.goto(f"{server.url}/#/inspections/{inspection}")
        page.click("[role=tab][data-tab=tolerances]")
        gap_max = "#tolerance-fields input[name='gap_mm.max']"
        page.wait_for_selector(gap_max)
        assert page.get_attribute(gap_max, "placeholder") == "default 3"
        assert page.input_value("#tolerance-fields input[name='surface.dent_depth_mm']") == "0.5"
        page.screenshot(path=str(tmp_path / f"tolerances-{width}.png"))
        page.close()
        assert errors == [], errors

    page = browser.new_page(viewport={"width": 1440, "height": 900})
    _sign_in(page, server.url)
    page.goto(f"{server.url}/#/inspections/{inspection}")
    page.click("[role=tab][data-tab=tolerances]")
    page.fill("#tolerance-fields input[name='gap_mm.max']", "2.5")
    page.click("#tolerance-save")
    page.wait_for_selector("#tolerance-status:has-text('Saved')")
    limits = http.get(f"/api/v1/inspections/{inspection}").json()["limits"]
    assert limits["gap_max_mm"] == 2.5 and limits["dent_depth_mm"] == 0.5  # kept
    page.fill("#tolerance-fields input[name='surface.dent_depth_mm']", "")
    page.click("#tolerance-save")
    page.wait_for_selector("#tolerance-status:has-text('Saved')")
    limits = http.get(f"/api/v1/inspections/{inspection}").json()["limits"]
    assert limits["dent_depth_mm"] == 0.2 and limits["scratch_depth_mm"] == 0.3
    page.select_option("#tolerance-sets", str(lining["id"]))
    page.click("#apply-set")
    wait_for(
        lambda: (
            page.text_content("#tolerance-status").startswith("Applied")
            or page.text_content("#tolerance-error")
        ),
        what="the set applied",
    )
    assert page.text_content("#tolerance-error") == ""
    page.wait_for_selector("#tolerance-applied:has-text('A320 lining')")
    assert "version 1" in page.text_content("#tolerance-applied")
    applied = http.get(f"/api/v1/inspections/{inspection}").json()
    assert applied["limits"]["step_max_mm"] == 0.8
    assert applied["tolerance_set"]["name"] == "A320 lining"

    # Another inspector reads the limits but cannot change them.
    page.click("#sign-out")
    page.fill("input[name=username]", "ivan")
    page.fill("input[name=password]", "ivan-pw")
    page.click("#sign-in-form button")
    page.wait_for_selector("#view-inspections:not([hidden])")
    page.goto(f"{server.url}/#/inspections/{inspection}")
    page.click("[role=tab][data-tab=tolerances]")
    page.wait_for_selector("#tolerance-owner:not([hidden])")
    assert page.is_disabled("#tolerance-fields input[name='gap_mm.max']")
    assert page.is_disabled("#tolerance-save")
    http.close()


def test_files_are_told_apart_and_a_picker_selects_all_of_a_kind(
    start_server, tmp_path, sqlite_url, browser
):
    """Two uploads named wing.ply are kept as wing.ply and wing (2).ply; the Files tab
    shows each file's kind, size, when, who, and a download; the stitch form's scan picker
    lists every scan on its own line and selects them all in one click."""
    from services.lib.pointcloud.ply import write_ply
    from tests.plyfiles import plane_grid

    settings = make_settings(tmp_path, sqlite_url)
    server = start_server(settings, run_engine=False)
    runtime = server.runtime
    add_user(runtime, "ines", "inspector", "ines-pw")
    http = httpx.Client(base_url=server.url, headers=auth(_token(server.url)), timeout=30)
    inspection = http.post("/api/v1/inspections", json={"title": "t", "area": "cabin"}).json()["id"]
    cloud = tmp_path / "wing.ply"
    write_ply(cloud, plane_grid(20, 20, spacing_mm=1.0))

    def upload(kind: str, name: str) -> dict:
        answer = http.post(
            f"/api/v1/inspections/{inspection}/artifacts",
            params={"kind": kind, "name": name},
            content=cloud.read_bytes(),
            headers={"content-type": "application/x-ply"},
        )
        assert answer.status_code == 201, answer.text
        return answer.json()

    first, second = upload("cloud", "wing.ply"), upload("cloud", "wing.ply")
    assert (first["name"], second["name"]) == ("wing.ply", "wing (2).ply")
    assert second["created_by_name"] == "ines" and second["run_id"] is None
    scans = [upload("scan", f"scan_{i:03d}.ply")["id"] for i in range(4)]

    page = browser.new_page(viewport={"width": 1024, "height": 768})
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    _sign_in(page, server.url)
    page.goto(f"{server.url}/#/inspections/{inspection}")
    page.click("[role=tab][data-tab=files]")
    row = f"#artifact-table tr[data-id='{second['id']}']"
    page.wait_for_selector(row)
    cells = page.locator(f"{row} td").all_text_contents()
    assert cells[0] == "wing (2).ply" and cells[1] == "cloud" and "uploaded by ines" in cells[4]
    with page.expect_download() as download:
        page.click(f"{row} button[data-download]")
    assert download.value.suggested_filename == "wing (2).ply"

    page.click("[role=tab][data-tab=timeline]")
    page.click("#run-box summary")
    page.select_option("#run-kind", "stitching.stitch")
    picker = "#run-inputs fieldset:has(.pick-all)"
    page.wait_for_selector(picker)
    assert page.locator(f"{picker} label.pick").count() == 4
    assert "scan_000.ply · scan ·" in page.text_content(f"{picker} label.pick >> nth=0")
    page.click(f"{picker} .pick-all")
    checked = page.eval_on_selector_all(
        f"{picker} input[type=checkbox]:checked", "boxes => boxes.map(b => Number(b.value))"
    )
    assert sorted(checked) == scans
    page.screenshot(path=str(tmp_path / "picker-1024.png"))
    http.close()
    assert errors == [], errors


def test_a_finding_added_by_clicking_the_scene_and_annotated(
    start_server, tmp_path, sqlite_url, browser
):
    """Add a finding: a click on the cloud places it, the form says what it is; it is
    listed and selected, its note shown; another note is added from its detail."""
    from services.lib.pointcloud.ply import write_ply
    from tests.plyfiles import plane_grid

    settings = make_settings(tmp_path, sqlite_url)
    server = start_server(settings, run_engine=False)
    runtime = server.runtime
    add_user(runtime, "ines", "inspector", "ines-pw")
    http = httpx.Client(base_url=server.url, headers=auth(_token(server.url)), timeout=30)
    inspection = http.post("/api/v1/inspections", json={"title": "t", "area": "wing"}).json()["id"]
    cloud = tmp_path / "panel.ply"
    write_ply(cloud, plane_grid(200, 200, spacing_mm=0.5))
    http.post(
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": "cloud", "name": "panel.ply"},
        content=cloud.read_bytes(),
        headers={"content-type": "application/x-ply"},
    ).raise_for_status()

    page = browser.new_page(viewport={"width": 1440, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    _sign_in(page, server.url)
    page.goto(f"{server.url}/#/inspections/{inspection}")
    page.wait_for_selector("#scene[data-drawn=true]")
    page.click("#add-finding")
    box = page.locator("#scene").bounding_box()
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.wait_for_selector("#new-finding:not([hidden])")
    assert "mm (base frame)" in page.text_content("#new-finding-where")
    page.select_option("#new-finding-type", "dent")
    page.select_option("#new-finding-severity", "major")
    page.fill("#new-finding-value", "0.35")
    page.fill("#new-finding-note", "felt it by hand")
    page.click("#new-finding button[type=submit]")
    page.wait_for_selector("#detail:not([hidden]) #notes li")
    assert "felt it by hand" in page.text_content("#notes")
    page.wait_for_selector("#scene-status:has-text('1 markers')")  # the scene drew it
    [made] = http.get("/api/v1/defects", params={"inspection": inspection}).json()["items"]
    assert (made["type"], made["severity"], made["value_mm"], made["source"]) == (
        "dent",
        "major",
        0.35,
        "manual",
    )
    x, y, z = made["location_mm"]
    assert abs(z) < 1.0 and 0 <= x <= 100 and 0 <= y <= 100  # a point of the plate
    page.fill("#note-text", "looked again: 0.4 mm")
    page.click("#note-form button")
    page.wait_for_selector("#notes li >> nth=1")
    notes = http.get(f"/api/v1/defects/{made['id']}").json()["notes"]
    assert [n["text"] for n in notes] == ["felt it by hand", "looked again: 0.4 mm"]
    page.screenshot(path=str(tmp_path / "by-hand-1440.png"))
    http.close()
    assert errors == [], errors


def test_a_list_of_numbers_is_typed_as_its_help_says(start_server, tmp_path, sqlite_url, browser):
    """tracking.track's init_box: seven numbers with spaces between, sent as a list; a word
    among them is refused in the form, naming the field."""
    settings = make_settings(tmp_path, sqlite_url)
    server = start_server(settings, run_engine=False)
    runtime = server.runtime
    add_user(runtime, "ines", "inspector", "ines-pw")
    http = httpx.Client(base_url=server.url, headers=auth(_token(server.url)), timeout=30)
    inspection = http.post(
        "/api/v1/inspections", json={"title": "drive 0048", "area": "street drive"}
    ).json()["id"]
    page = browser.new_page(viewport={"width": 1440, "height": 900})
    _sign_in(page, server.url)
    page.goto(f"{server.url}/#/inspections/{inspection}")
    page.click("[role=tab][data-tab=timeline]")
    page.click("#run-box summary")
    page.select_option("#run-kind", "tracking.track")
    page.click("#run-form details.params summary")
    box = "#run-params [data-param=init_box]"
    assert "7 numbers" in page.get_attribute(box, "placeholder")
    page.fill(box, "1.5 1.6 three 0 1.7 10 0")
    page.click("#run-form button[type=submit]")
    page.wait_for_selector("#run-error:has-text('init_box')")
    page.fill(box, "1.5 1.6 3.9 0 1.7 10 -1.56")
    with page.expect_request(lambda r: r.url.endswith("/runs") and r.method == "POST") as sent:
        page.click("#run-form button[type=submit]")
    params = sent.value.post_data_json["steps"][0]["params"]
    assert params["init_box"] == [1.5, 1.6, 3.9, 0, 1.7, 10, -1.56]
    http.close()
