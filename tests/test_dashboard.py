"""The web dashboard end to end in Debian's Chromium (headless, driven by Playwright):
sign in, open the inspection `vista demo` made, select a defect, see the scene drawn,
judge it and watch the consensus change — also when another user judges meanwhile."""

from __future__ import annotations

import io
import shutil

import httpx
import numpy as np
import pytest
from PIL import Image

from benches.browser import launch_chromium
from supervisor.demo import DEMO_USER, run_demo
from supervisor.engine.runtime import Runtime
from supervisor.records import DomainRecords
from tests.conftest import LiveServer, add_user, auth, make_settings, wait_for
from tests.seeding import measure_uploaded


@pytest.fixture(scope="module")
def demo_server(tmp_path_factory, sqlite_template):
    """One demo for the module's tests (it takes half a minute): the first reviews it, the
    second adds a measurement; neither depends on what the other did."""
    tmp_path = tmp_path_factory.mktemp("demo")
    shutil.copy(sqlite_template, tmp_path / "vista.db")
    settings = make_settings(
        tmp_path, f"sqlite:///{tmp_path / 'vista.db'}", embedded_workers=2, extra_job_kinds=[]
    )
    demo = run_demo(settings, spacing_mm=0.2, seed=0, timeout_s=300, say=lambda line: None)
    runtime = Runtime.create(settings, records=DomainRecords())
    server = LiveServer(settings, runtime, run_engine=True).start()  # it measures what a test adds
    other = add_user(runtime, "olga", "inspector", "olga-pw")
    yield server, demo, other
    server.stop()
    runtime.db.dispose()


def _times_the_limit(defect: dict) -> float:
    """How far out of tolerance, as the dashboard sorts: a multiple of the limit."""
    value, limit = abs(defect["measurements"]["value"]), defect["measurements"]["tolerance"]
    below = defect["type"] == "gap" and defect["measurements"]["value"] < limit
    return limit / value if below else value / limit


def test_review_an_inspection_in_the_browser(demo_server):
    server, demo, other_token = demo_server
    inspection = demo["inspection"]["id"]
    out_of_tolerance = [d for d in demo["defects"] if d["severity"] != "info"]
    target = out_of_tolerance[0]["id"]
    httpx.put(
        f"{server.url}/api/v1/defects/{target}/judgments/me",
        json={"verdict": "rejected", "comment": "looks like a reflection"},
        headers=auth(other_token),
    ).raise_for_status()

    with launch_chromium() as browser:
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        csp: list[str] = []  # the security headers must not block the dashboard
        page.on(
            "console",
            lambda m: csp.append(m.text) if "Content Security Policy" in m.text else None,
        )
        page.goto(server.url + "/")
        assert page.locator("#view-inspection").is_hidden()  # not under the sign-in form
        page.fill("input[name=username]", DEMO_USER)
        page.fill("input[name=password]", "wrong")
        page.click("#sign-in-form button")
        page.wait_for_selector("#sign-in-error:has-text('wrong password')")
        page.fill("input[name=password]", demo["password"])
        page.click("#sign-in-form button")
        page.click(f"#inspection-table tr[data-id='{inspection}']")
        page.wait_for_selector("#defect-list .row")
        assert page.locator("#defect-list .row").count() == len(demo["defects"])

        page.select_option("#filter-severity", "out")
        assert page.locator("#defect-list .row").count() == len(out_of_tolerance)
        page.select_option("#sort", "value")  # how far out of tolerance: worst first
        first = int(page.get_attribute("#defect-list .row >> nth=0", "data-id"))
        assert first == max(out_of_tolerance, key=_times_the_limit)["id"]
        assert "review" in page.text_content("#inspection-status")  # it followed its runs
        page.click(f"#defect-list .row[data-id='{target}']")
        page.wait_for_selector(f"#detail-title:has-text('#{target} ')")
        facts = page.text_content("#detail-facts")
        measured = out_of_tolerance[0]["measurements"]
        assert f"value{measured['value']:.3f} " in facts, facts
        page.wait_for_selector("#scene[data-drawn=true]")
        page.wait_for_selector("#scene-status:has-text('markers')", timeout=30_000)
        # the measured panels are outlined and labelled, and the finding says which they are
        assert "4 panels (P0…)" in page.text_content("#scene-status")  # labels drawn
        panels = measured["panels"]  # a gap: the first finding of the first seam
        assert f"seam{measured['seam']}, between P{panels[0]} and P{panels[1]}" in facts
        assert f"along the seam{measured['along_mm']:.1f} mm from its start" in facts
        # a legend of every type on show, one colour each, and a scale bar
        legend = page.locator("#legend li").all_text_contents()
        page.click("#legend-box summary")  # the legend folds away, and opens again
        assert page.locator("#legend").is_hidden()
        page.click("#legend-box summary")
        types = {d["type"] for d in demo["defects"]}
        assert types <= set(legend) and "seam" in legend
        assert int(page.get_attribute("#scale-bar", "data-mm")) > 0
        assert page.text_content("#consensus") == "Consensus: 1/1 rejected"
        assert "looks like a reflection" in page.text_content("#judgments li[data-user=olga]")

        page.wait_for_timeout(800)  # the camera's flight to the defect
        pixels = np.asarray(Image.open(io.BytesIO(page.locator("#scene").screenshot())))
        background = np.array([15, 23, 34])
        drawn = np.abs(pixels[..., :3].astype(int) - background).sum(axis=-1) > 30
        assert drawn.mean() > 0.05, f"only {drawn.mean():.1%} of the canvas is drawn"
        # the selection's aquamarine (#1de9b6), no type's colour: the ring and the thick seam
        red, green, blue = (pixels[..., c].astype(int) for c in range(3))
        highlight = (red < 90) & (green > 200) & (blue > 150) & (blue < 225)
        assert highlight.sum() > 50, "the selected defect's marker is not on screen"

        page.fill("#comment", "confirmed on site")
        page.click(".verdicts button[data-verdict=confirmed]")
        page.wait_for_selector("#consensus:has-text('split 2 · needs review')")
        assert "confirmed on site" in page.text_content(f"#judgments li[data-user={DEMO_USER}]")
        row = f"#defect-list .row[data-id='{target}'] .verdict"
        assert page.text_content(row) == "split 2 · needs review"

        # Another reviewer confirms too: the open page picks it up by itself.
        httpx.put(
            f"{server.url}/api/v1/defects/{target}/judgments/me",
            json={"verdict": "confirmed"},
            headers=auth(other_token),
        ).raise_for_status()
        page.wait_for_selector(f"{row}:has-text('2/2 confirmed')", timeout=10_000)

        # Judging the next defect starts from an empty form: each comment stays with its own.
        second = out_of_tolerance[1]["id"]
        page.click(f"#defect-list .row[data-id='{second}']")
        page.wait_for_selector(f"#detail-title:has-text('#{second} ')")
        assert page.input_value("#comment") == ""
        page.fill("#comment", "a reflection off the lamp")
        page.click(".verdicts button[data-verdict=rejected]")
        page.wait_for_selector(f"#judgments li[data-user={DEMO_USER}]:has-text('lamp')")
        page.click(f"#defect-list .row[data-id='{target}']")
        page.wait_for_selector(f"#detail-title:has-text('#{target} ')")
        assert page.input_value("#comment") == "confirmed on site"  # my own judgment's
        stored = {
            defect: {
                j["username"]: j["comment"]
                for j in httpx.get(
                    f"{server.url}/api/v1/defects/{defect}/judgments", headers=auth(other_token)
                ).json()["judgments"]
            }[DEMO_USER]
            for defect in (target, second)
        }
        assert stored == {target: "confirmed on site", second: "a reflection off the lamp"}

        # a gap shows both ends of its acceptable range
        gap = next(d for d in out_of_tolerance if d["type"] == "gap")
        page.click(f"#defect-list .row[data-id='{gap['id']}']")
        page.wait_for_selector(f"#detail-title:has-text('#{gap['id']} ')")
        assert "limits0.50–3.00 mm" in page.text_content("#detail-facts")

        page.click("[role=tab][data-tab=timeline]")
        assert page.locator("#timeline .job").count() == 3
        assert page.locator("#timeline .job .status-succeeded").count() == 3
        page.click("[role=tab][data-tab=feedback]")
        page.wait_for_selector("#feedback-table tbody tr")
        units = page.text_content("#feedback-table")
        assert "ΔE" in units and "delta_e" not in units

        # The layout holds at 1024 px: the feedback table and each row's severity fit.
        page.set_viewport_size({"width": 1024, "height": 768})
        page.wait_for_timeout(300)
        table = "document.querySelector('#tab-feedback .table-scroll')"
        assert page.evaluate(f"{table}.scrollWidth <= {table}.clientWidth")
        page.click("[role=tab][data-tab=defects]")
        cut = page.evaluate(
            """[...document.querySelectorAll('#defect-list .row')].filter((row) => {
                const chip = row.querySelector('.severity').getBoundingClientRect();
                return chip.width === 0 || chip.right > row.getBoundingClientRect().right;
            }).length"""
        )
        assert cut == 0
        # nothing runs off the page's right edge (a long run name once widened the scene)
        assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth")
        box = page.locator("#scene").bounding_box()
        assert box["x"] + box["width"] <= 1024

        # Sign out revokes the token on the server, not only in this browser.
        token = page.evaluate("sessionStorage.getItem('vista.token')")
        assert (
            token and httpx.get(f"{server.url}/api/v1/me", headers=auth(token)).status_code == 200
        )
        page.click("#sign-out")
        page.wait_for_selector("#sign-in-form")
        assert page.input_value("input[name=password]") == ""
        assert httpx.get(f"{server.url}/api/v1/me", headers=auth(token)).status_code == 401
        assert errors == [] and csp == []


def test_each_measured_run_shows_its_own_scene_and_an_open_page_follows(demo_server, tmp_path):
    """A colleague measures a flat plate while the demo's inspection is open: the page
    draws the plate's scene by itself (its one panel, none of the assembly's rings) and
    lists that run's findings; the run picker brings back the assembly's scene and list,
    and selecting a finding of another run shows that run's scene."""
    from services.lib.pointcloud.ply import write_ply
    from tests.plyfiles import plane_grid

    server, demo, other_token = demo_server
    inspection = demo["inspection"]["id"]
    demo_run = demo["defects"][0]["run_id"]
    with launch_chromium() as browser:
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(server.url + "/")
        page.fill("input[name=username]", DEMO_USER)
        page.fill("input[name=password]", demo["password"])
        page.click("#sign-in-form button")
        page.click(f"#inspection-table tr[data-id='{inspection}']")
        page.wait_for_selector("#scene-status:has-text('4 panels')", timeout=30_000)
        assert page.locator("#scene-run option").count() == 2  # the newest, and its run
        assert page.locator("#defect-list .row").count() == len(demo["defects"])
        page.click("#defect-list .row >> nth=0")  # selected when another run's scene arrives
        page.wait_for_selector("#detail:not([hidden])")

        plate = tmp_path / "plate.ply"
        write_ply(plate, plane_grid(400, 400, spacing_mm=0.5))
        http = httpx.Client(base_url=server.url, headers=auth(other_token), timeout=30)
        run = measure_uploaded(http, inspection, plate)
        page.wait_for_selector("#scene-status:has-text('1 panel (P0)')", timeout=60_000)
        assert page.locator("#detail").is_hidden()  # the finding is not on the plate's scene
        assert "/defects/" not in page.evaluate("location.hash")
        assert page.locator("#scene-run option").count() == 3
        assert "plate.ply" in page.text_content("#scene-run option >> nth=0")
        assert page.locator("#defect-list .row").count() == 0  # the plate's: none
        assert f"run {run['id']}'s" in page.text_content("#defect-count")

        page.select_option("#scene-run", str(demo_run))
        page.wait_for_selector("#scene-status:has-text('4 panels')", timeout=30_000)
        assert page.locator("#defect-list .row").count() == len(demo["defects"])
        page.select_option("#scene-run", "")  # back to the newest: the plate
        page.wait_for_selector("#scene-status:has-text('1 panel (P0)')", timeout=30_000)
        target = demo["defects"][0]["id"]  # a finding of the assembly's run, by its link
        page.goto(f"{server.url}/#/inspections/{inspection}/defects/{target}")
        page.wait_for_selector("#scene-status:has-text('4 panels')", timeout=30_000)
        assert page.input_value("#scene-run") == str(demo_run)
        http.close()
    assert errors == []


def test_api_docs_work_offline(start_server, tmp_path, sqlite_url):
    """/docs and /redoc draw the API from assets the supervisor serves: any request to
    another host is blocked, as on a plant network without internet."""
    server = start_server(make_settings(tmp_path, sqlite_url), run_engine=False)
    elsewhere: list[str] = []

    def only_local(route):
        if route.request.url.startswith(server.url):
            route.continue_()
        else:
            elsewhere.append(route.request.url)
            route.abort()

    with launch_chromium() as browser:
        page = browser.new_page(viewport={"width": 1024, "height": 768})
        page.route("**/*", only_local)
        page.goto(server.url + "/docs")
        page.wait_for_selector(".swagger-ui .info .title:has-text('vista supervisor')")
        assert page.locator(".swagger-ui .opblock").count() > 30  # every operation listed
        page.goto(server.url + "/redoc")
        page.wait_for_selector("h1:has-text('vista supervisor')", timeout=30_000)
        assert "/api/v1/inspections" in page.text_content("body")
    # Redoc's bundle asks a CDN for its own small logo (Redocly/redoc#2108) and shows the
    # page without it; nothing else leaves the machine.
    assert set(elsewhere) <= {"https://cdn.redoc.ly/redoc/logo-mini.svg"}


def test_measuring_again_keeps_the_judgments_in_the_browser(demo_server, tmp_path):
    """The demo's stitched cloud measured again: the list shows each finding once (the new
    run's), the one Olga rejected keeps her verdict, marked as judged on the first run, the
    'rejected' filter finds it, and its detail shows its history across the two runs."""
    server, demo, other_token = demo_server
    inspection = demo["inspection"]["id"]
    demo_run = demo["run"]["id"]
    http = httpx.Client(base_url=server.url, headers=auth(other_token), timeout=30)
    judged = next(  # one the other tests leave alone
        d
        for d in reversed(demo["defects"])
        if d["severity"] != "info"
        and not http.get(f"/api/v1/defects/{d['id']}/judgments").json()["judgments"]
    )
    http.put(
        f"/api/v1/defects/{judged['id']}/judgments/me",
        json={"verdict": "rejected", "comment": "a reflection"},
    ).raise_for_status()
    stitched = next(
        a
        for a in http.get(
            f"/api/v1/inspections/{inspection}/artifacts", params={"limit": 100}
        ).json()["items"]
        if a["kind"] == "cloud" and a["job_id"] is not None
    )
    again = http.post(
        f"/api/v1/inspections/{inspection}/runs",
        json={
            "name": "measure again",
            "steps": [{"name": "measure", "kind": "defects.measure", "inputs": [stitched["id"]]}],
        },
    ).json()
    wait_for(
        lambda: http.get(f"/api/v1/runs/{again['id']}").json()["status"] == "succeeded",
        timeout=240,
        what="the second measurement",
    )
    current = http.get("/api/v1/defects", params={"inspection": inspection, "limit": 500}).json()[
        "items"
    ]
    successor = next(d for d in current if d["supersedes_id"] == judged["id"])
    found_again = [d for d in current if d["run_id"] == again["id"]]

    with launch_chromium() as browser:
        for width, height in ((1440, 900), (1024, 768)):
            page = browser.new_page(viewport={"width": width, "height": height})
            errors: list[str] = []
            page.on("pageerror", lambda error, errors=errors: errors.append(str(error)))
            page.goto(server.url + "/")
            page.fill("input[name=username]", DEMO_USER)
            page.fill("input[name=password]", demo["password"])
            page.click("#sign-in-form button")
            page.goto(f"{server.url}/#/inspections/{inspection}")
            page.wait_for_selector("#defect-list .row")
            page.select_option("#scene-run", str(again["id"]))
            page.wait_for_selector(f"#defect-count:has-text('run {again['id']}')")
            assert page.locator("#defect-list .row").count() == len(found_again)
            page.select_option("#filter-consensus", "rejected")
            rows = page.eval_on_selector_all(
                "#defect-list .row", "rows => rows.map(r => r.dataset.id)"
            )
            rejected = [d for d in found_again if d["consensus"]["majority"] == "rejected"]
            assert sorted(rows) == sorted(str(d["id"]) for d in rejected)
            assert str(successor["id"]) in rows
            page.click(f"#defect-list .row[data-id='{successor['id']}']")
            page.wait_for_selector("#judgments li[data-user='olga'] .judged-on")
            assert f"judged on run {demo_run}" in page.text_content("#judgments")
            page.wait_for_selector("#lineage-steps li >> nth=1")
            steps = page.locator("#lineage-steps li").all_text_contents()
            assert f"run {demo_run}" in steps[0] and "measured again" in steps[0]
            assert "olga: rejected" in steps[0] and "current" in steps[1]
            page.screenshot(path=str(tmp_path / f"lineage-{width}.png"))
            page.close()
            assert errors == []
    http.close()
