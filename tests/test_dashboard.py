"""The web dashboard end to end in Debian's Chromium (headless, driven by Playwright):
sign in, open the inspection `vista demo` made, select a defect, see the scene drawn,
judge it and watch the consensus change — also when another user judges meanwhile."""

from __future__ import annotations

import io

import httpx
import numpy as np
import pytest
from PIL import Image

from supervisor.bench.browser import launch_chromium
from supervisor.demo import DEMO_PASSWORD, DEMO_USER, run_demo
from supervisor.engine.runtime import Runtime
from tests.conftest import add_user, auth, make_settings


@pytest.fixture
def demo_server(start_server, tmp_path, sqlite_url):
    settings = make_settings(tmp_path, sqlite_url, embedded_workers=2, extra_job_kinds=[])
    demo = run_demo(settings, spacing_mm=0.3, seed=0, timeout_s=300, say=lambda line: None)
    server = start_server(settings, run_engine=False)
    runtime = Runtime.create(settings)
    other = add_user(runtime, "olga", "inspector", "olga-pw")
    yield server, demo, other
    runtime.db.dispose()


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
        page.goto(server.url + "/")
        page.fill("input[name=username]", DEMO_USER)
        page.fill("input[name=password]", "wrong")
        page.click("#sign-in-form button")
        page.wait_for_selector("#sign-in-error:has-text('wrong password')")
        page.fill("input[name=password]", DEMO_PASSWORD)
        page.click("#sign-in-form button")
        page.click(f"#inspection-table tr[data-id='{inspection}']")
        page.wait_for_selector("#defect-list .row")
        assert page.locator("#defect-list .row").count() == len(demo["defects"])

        page.select_option("#filter-severity", "out")
        assert page.locator("#defect-list .row").count() == len(out_of_tolerance)
        page.select_option("#sort", "value")
        page.click("#sort-direction")  # largest excess first
        page.click(f"#defect-list .row[data-id='{target}']")
        page.wait_for_selector(f"#detail-title:has-text('#{target} ')")
        facts = page.text_content("#detail-facts")
        measured = out_of_tolerance[0]["measurements"]
        assert f"value{measured['value']:.3f} " in facts, facts
        page.wait_for_selector("#scene[data-drawn=true]")
        page.wait_for_selector("#scene-status:has-text('markers')", timeout=30_000)
        # the measured panels are outlined and labelled, and the finding says which they are
        assert "4 panels (P0…)" in page.text_content("#scene-status")  # labels drawn
        if "seam" in measured:
            panels = measured["panels"]
            assert f"seam {measured['seam']}: P{panels[0]} → P{panels[1]}" in facts, facts
        assert page.text_content("#consensus") == "Consensus: 1/1 rejected"
        assert "looks like a reflection" in page.text_content("#judgments li[data-user=olga]")

        page.wait_for_timeout(800)  # the camera's flight to the defect
        pixels = np.asarray(Image.open(io.BytesIO(page.locator("#scene").screenshot())))
        background = np.array([15, 23, 34])
        drawn = np.abs(pixels[..., :3].astype(int) - background).sum(axis=-1) > 30
        assert drawn.mean() > 0.05, f"only {drawn.mean():.1%} of the canvas is drawn"
        highlight = (pixels[..., 0] > 200) & (pixels[..., 1] > 180) & (pixels[..., 2] < 120)
        assert highlight.sum() > 50, "the selected defect's yellow marker is not on screen"

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

        page.click("[role=tab][data-tab=timeline]")
        assert page.locator("#timeline .job").count() == 3
        assert page.locator("#timeline .status-succeeded").count() == 3
        page.click("[role=tab][data-tab=feedback]")
        page.wait_for_selector("#feedback-table tbody tr")
        assert errors == []
