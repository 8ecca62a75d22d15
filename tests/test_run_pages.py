"""Each job's run page in Debian's Chromium, on results made by the real jobs: an odometry
run on a short simulated sequence (its path, 1σ band, truth and error against distance,
figures), its OE-Net training (loss and validation per epoch) and a depth prediction on
two real KITTI frames (the camera image and its depth map, a slider between them)."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from supervisor.bench.browser import launch_chromium
from tests.conftest import add_user, auth, make_settings, wait_for

KITTI_IMAGES = (
    Path(__file__).resolve().parents[2] / "shared/data/kitti-object-testing-sample/image_2"
)


@pytest.fixture
def finished_jobs(start_server, tmp_path, sqlite_url):
    """A live server whose engine ran the jobs: (server URL, token, inspection, jobs by step)."""
    from tests.sequences import pack, small_sequence

    server = start_server(make_settings(tmp_path, sqlite_url, embedded_workers=1))
    token = add_user(server.app.state.runtime, "perception", "inspector", "perception-pw")
    http = httpx.Client(base_url=server.url, headers=auth(token), timeout=30)
    inspection = http.post(
        "/api/v1/inspections", json={"title": "perception", "area": "component"}
    ).json()["id"]

    def upload(path: Path, kind: str, media_type: str) -> int:
        response = http.post(
            f"/api/v1/inspections/{inspection}/artifacts",
            params={"kind": kind, "name": path.name},
            content=path.read_bytes(),
            headers={"content-type": media_type},
        )
        assert response.status_code == 201, response.text
        return response.json()["id"]

    frames = upload(
        pack(small_sequence(tmp_path / "seq", seconds=0.3), tmp_path / "seq.tar.gz"),
        "frames",
        "application/gzip",
    )
    steps = [
        {"name": "odometry", "kind": "odometry.run", "inputs": [frames]},
        {"name": "train", "kind": "odometry.train", "inputs": [frames], "params": {"epochs": 2, "batch": 8, "device": "cpu"}},
    ]  # fmt: skip
    if KITTI_IMAGES.is_dir():
        images = [upload(KITTI_IMAGES / f"{n:06d}.png", "image", "image/png") for n in (0, 1)]
        steps.append({"name": "depth", "kind": "depth.predict", "inputs": images})
    run = http.post(f"/api/v1/inspections/{inspection}/runs", json={"steps": steps}).json()
    jobs = {}
    for job in run["jobs"]:
        jobs[job["step"]] = wait_for(
            lambda j=job: (
                (d := http.get(f"/api/v1/jobs/{j['id']}").json())["status"]
                in ("succeeded", "failed")
                and d
            ),
            timeout=240,
            what=f"job {job['step']}",
        )
        assert jobs[job["step"]]["status"] == "succeeded", jobs[job["step"]]
    yield server.url, token, inspection, jobs
    http.close()


def _open(browser, url: str, token: str, inspection: int, job: dict, errors: list[str]):
    page = browser.new_page(viewport={"width": 1440, "height": 1000})
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(url + "/")
    page.evaluate(f"sessionStorage.setItem('vista.token', {token!r})")
    page.goto(f"{url}/#/inspections/{inspection}/jobs/{job['id']}")
    page.wait_for_selector("#job-status:has-text('succeeded')")
    return page


def test_run_pages_draw_each_result(finished_jobs, tmp_path):
    url, token, inspection, jobs = finished_jobs
    errors: list[str] = []
    with launch_chromium() as browser:
        page = _open(browser, url, token, inspection, jobs["odometry"], errors)
        page.wait_for_selector("svg.plot")
        assert page.locator("svg.plot").count() == 2  # the path, the error against distance
        estimate = page.locator(".series[data-name='estimate (±1σ)'] polyline")
        assert len(estimate.get_attribute("points").split()) == 19
        assert page.locator(".series[data-name='estimate (±1σ)'] circle.band").count() == 19
        assert page.locator(".series[data-name='truth'] polyline").count() == 1
        figures = page.text_content(".panel-figures")
        assert "drift" in figures and "pairs per second" in figures
        assert page.locator("#job-outputs .files li").count() == 4
        assert page.locator("#job-params").count() == 1  # method: vista
        page.screenshot(path=str(tmp_path / "odometry.png"), full_page=True)
        # a path's axes are equal: a metre is as many pixels across as up
        across, up = map(
            float, page.get_attribute("svg.plot >> nth=0", "data-units-per-px").split()
        )
        assert across == pytest.approx(up, rel=1e-9)
        across, up = map(
            float, page.get_attribute("svg.plot >> nth=1", "data-units-per-px").split()
        )
        assert across != pytest.approx(up, rel=0.01)  # the error plot fills its box

        page = _open(browser, url, token, inspection, jobs["train"], errors)
        page.wait_for_selector(".panel-plot[data-title='Training']")
        points = page.locator(".series[data-name='training loss'] polyline").get_attribute("points")
        assert len(points.split()) == 2  # one per epoch
        assert "oenet" in page.text_content(".panel-figures")

        if "depth" in jobs:
            page = _open(browser, url, token, inspection, jobs["depth"], errors)
            page.wait_for_selector(".picture")
            assert page.locator(".picture").count() == 2
            wait_for(
                lambda: page.evaluate(
                    "[...document.querySelectorAll('.picture img')].every(i => i.complete && i.naturalWidth > 0)"
                ),
                what="the camera images and depth maps",
            )
            assert page.locator(".picture img").count() == 4
            first = page.locator(".picture >> nth=0")
            first.locator("input[type=range]").fill("100")
            opacities = first.locator("img").evaluate_all("(i) => i.map(x => x.style.opacity)")
            assert opacities == ["0", "1"]  # slid over to the depth map
            page.screenshot(path=str(tmp_path / "depth.png"), full_page=True)
    assert errors == []
