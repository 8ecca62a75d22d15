"""Each job's run page in Debian's Chromium, and its glTF scene through the Khronos
validator, on results made by the real jobs: an odometry run on a short simulated sequence
(its path, 1σ band, truth and error against distance, figures), its OE-Net training (loss
and validation per epoch), a track through a simulated LiDAR drive (confidence, the box's
path; in 3D the scans and the box moving through them) and through real KITTI scans, the
cars detected in both (in 3D each scan with its boxes, judged against the labels) and in
real scans with their camera images (the images with the 2D boxes), and a depth prediction
on two real KITTI frames (the camera image and its depth map, a slider between them; the
clouds)."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from benches.browser import launch_chromium
from tests.conftest import add_user, auth, make_settings, wait_for
from tests.lidarfiles import REAL_DRIVE, REAL_LABELLED_DRIVE

KITTI_IMAGES = (
    Path(__file__).resolve().parents[2] / "shared/data/kitti-object-testing-sample/image_2"
)


@pytest.fixture
def finished_jobs(start_server, tmp_path, sqlite_url):
    """A live server whose engine ran the jobs: (server URL, token, inspection, jobs by step)."""
    from tests.lidarfiles import pack_sequence, small_drive
    from tests.sequences import pack, small_sequence

    server = start_server(make_settings(tmp_path, sqlite_url, embedded_workers=1))
    token = add_user(server.app.state.runtime, "perception", "inspector", "perception-pw")
    http = httpx.Client(base_url=server.url, headers=auth(token), timeout=30)
    inspection = http.post(
        "/api/v1/inspections", json={"title": "perception", "area": "component"}
    ).json()["id"]

    def upload(path: Path, kind: str, media_type: str, into: int | None = None) -> int:
        response = http.post(
            f"/api/v1/inspections/{into or inspection}/artifacts",
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
    drive = pack_sequence(small_drive(tmp_path / "drive"), tmp_path / "drive.tar.gz")
    lidar = upload(drive, "lidar", "application/gzip")
    steps += [
        {"name": "track", "kind": "tracking.track", "inputs": [lidar], "params": {"track_id": 0}},
        {"name": "detect", "kind": "tracking.detect", "inputs": [lidar]},
    ]
    if REAL_LABELLED_DRIVE.is_dir():  # real KITTI scans, held out of the detector's training
        from services.tracking.sample import packed_real_drive

        archive, longest, _ = packed_real_drive(REAL_LABELLED_DRIVE, tmp_path / "kitti-0048")
        real = upload(archive, "lidar", "application/gzip")
        steps.append({"name": "real-track", "kind": "tracking.track", "inputs": [real], "params": {"track_id": longest}})  # fmt: skip
    if REAL_DRIVE.is_dir():  # real scans with their camera images
        from services.tracking.sample import packed_camera_drive

        archive, pictures = packed_camera_drive(REAL_DRIVE, tmp_path / "kitti-0052", 2)
        inputs = [upload(archive, "lidar", "application/gzip")]
        inputs += [upload(picture, "image", "image/png") for picture in pictures]
        steps.append({"name": "camera-detect", "kind": "tracking.detect", "inputs": inputs})
    if KITTI_IMAGES.is_dir():
        images = [upload(KITTI_IMAGES / f"{n:06d}.png", "image", "image/png") for n in (0, 1)]
        truth = upload(KITTI_IMAGES.parent / "depth" / "000000.png", "depth", "image/png")
        steps.append({"name": "depth", "kind": "depth.predict", "inputs": [*images, truth]})
    run = http.post(f"/api/v1/inspections/{inspection}/runs", json={"steps": steps}).json()
    # a part compared with its nominal, in an inspection of its own (the one above holds
    # perception runs only)
    from tests.test_compare import _write_plate

    part = http.post("/api/v1/inspections", json={"title": "plate", "area": "component"})
    part = part.json()["id"]
    cloud, nominal = _write_plate(tmp_path)
    plate = [
        upload(cloud, "cloud", "application/x-ply", part),
        upload(nominal, "nominal", "model/stl", part),
    ]
    compare = {"name": "compare", "kind": "defects.compare", "inputs": plate}
    compared = http.post(f"/api/v1/inspections/{part}/runs", json={"steps": [compare]}).json()
    jobs = {}
    for job in run["jobs"] + compared["jobs"]:
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


def test_run_pages_and_scenes_of_each_result(finished_jobs, tmp_path):
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
        assert page.locator("#job-log li").count() >= 2  # unpacking … 18 pairs
        # its 3D view reads: axes and a grid with their lengths, the path's start and end,
        # a legend of its colours
        page.wait_for_selector("#player-scale:has-text('grid:')")
        assert int(page.get_attribute("#job-scene canvas", "data-path-ends")) >= 1
        legend = page.text_content(".player-legend")
        assert "path" in legend and "truth" in legend
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

        page = _open(browser, url, token, inspection, jobs["track"], errors)
        page.wait_for_selector(".panel-plot[data-title='Confidence over the drive']")
        titles = page.locator(".panel").evaluate_all("(p) => p.map(x => x.dataset.title)")
        assert titles == [
            "Confidence over the drive",
            "The box's path from above (LiDAR frame)",
            "Success (OPE)",
            "Precision (OPE)",
            "Run",
        ]
        points = page.locator(".series[data-name='confidence'] polyline").get_attribute("points")
        assert len(points.split()) == 12
        assert "success (OPE, AUC of IoU)" in page.text_content(".panel-figures")
        # the drive in 3D: its scans and the box, played from the scene's own animation
        page.wait_for_selector("#scene-note:has-text('12 frames')")
        first = page.locator("#job-scene canvas").screenshot()
        page.click("#player-next")
        assert page.text_content("#player-frame") == "frame 2 / 12"
        page.locator("#player-scrub").fill("11")
        assert page.text_content("#player-frame") == "frame 12 / 12"
        wait_for(
            lambda: page.locator("#job-scene canvas").screenshot() != first, what="frame 12 drawn"
        )
        page.click("#player-play")
        wait_for(lambda: page.text_content("#player-frame") != "frame 12 / 12", what="playing on")
        page.click("#player-play")  # pause
        assert "drawn in the last second" in page.text_content("#player-fps")
        legend = page.text_content(".player-legend")
        assert "scan points by height" in legend and "the tracked car" in legend
        assert page.locator(".player-legend .swatch.gradient").count() == 1
        page.screenshot(path=str(tmp_path / "track.png"), full_page=True)

        if "real-track" in jobs:  # real KITTI scans: ~120 000 points each
            page = _open(browser, url, token, inspection, jobs["real-track"], errors)
            frames = jobs["real-track"]["result"]["frames"]
            page.wait_for_selector(f"#scene-note:has-text('{frames} frames')", timeout=60_000)
            assert "success (OPE, AUC of IoU)" in page.text_content(".panel-figures")
            page.locator("#player-scrub").fill(str(frames // 2))
            assert page.text_content("#player-frame") == f"frame {frames // 2 + 1} / {frames}"
            # the player shows that one frame's scan, every point the scene holds of it
            scene = gltf_json(
                httpx.get(
                    f"{url}/api/v1/jobs/{jobs['real-track']['id']}/scene.glb",
                    headers=auth(token),
                    timeout=60,
                ).content
            )
            scans = [n for n in scene["nodes"] if n["name"].startswith("scan-")]
            mesh = scene["meshes"][scans[frames // 2]["mesh"]]
            held = scene["accessors"][mesh["primitives"][0]["attributes"]["POSITION"]]["count"]
            assert int(page.get_attribute("#job-scene canvas", "data-points")) == held > 1000
            page.screenshot(path=str(tmp_path / "real-track.png"), full_page=True)

        _check_detection_pages(browser, url, token, inspection, jobs, errors, tmp_path)

        if "depth" in jobs:
            page = _open(browser, url, token, inspection, jobs["depth"], errors)
            _wait_for_pictures(page, 2, 5, 0)  # 000000 has its ground truth: 5 layers
            first = page.locator(".picture >> nth=0")
            first.locator("input[type=range]").fill("100")
            opacities = first.locator("img").evaluate_all("(i) => i.map(x => x.style.opacity)")
            assert opacities == ["0", "1", "0"]  # slid over to the depth map
            assert first.locator(".colour-bar").is_hidden()  # the depth map has its own bar
            first.locator("input[type=range]").fill("200")
            assert "error against ground truth" in first.text_content()
            assert first.locator(".colour-bar").is_visible()  # the error layer's: 0 → ≥ 50 %
            assert "≥ 50 %" in first.locator(".colour-bar").text_content()
            figures = page.text_content(".panel-figures")
            assert "AbsRel" in figures and "δ < 1.25" in figures and "images scored1" in figures
            page.wait_for_selector("#scene-note:has-text('drag to turn')")  # the clouds in 3D
            assert page.locator("#player-play").is_hidden()  # no frames to play
            # two unrelated images: one cloud at a time, picked by its image's name
            picker = page.locator("#player-pick")
            assert picker.is_visible() and picker.locator("option").count() == 2
            shown = page.get_attribute("#job-scene canvas", "data-shown")
            picker.select_option(index=1)
            assert page.get_attribute("#job-scene canvas", "data-shown") != shown
            assert "each image's own colours" in page.text_content(".player-legend")
            page.screenshot(path=str(tmp_path / "depth.png"), full_page=True)
        # A comparison with its nominal: the alignment, the regions, the findings, the
        # histogram with its colour bar, the coloured scan in 3D.
        compare = jobs["compare"]
        page = _open(browser, url, token, compare["inspection_id"], compare, errors)
        page.wait_for_selector(".picture img")
        figures = page.text_content(".panel-figures")
        assert "best-fit" in figures and "residual, robust σ" in figures
        tables = page.locator(".rows-table").all_text_contents()
        assert any("top" in t and "edges" in t for t in tables)  # the regions
        assert any("Deviations beyond the band" in t or "critical" in t for t in tables)
        loaded = page.locator(".picture img").evaluate_all("(i) => i.map(x => x.naturalWidth)")
        assert loaded and all(w > 0 for w in loaded)
        assert "+0.5 mm" in page.text_content(".picture")  # the bar: the default ±0.5 band
        page.wait_for_selector("#scene-note:has-text('drag to turn')")
        page.screenshot(path=str(tmp_path / "compare.png"), full_page=True)
        # its inspection: the deviation findings listed, the scan over its nominal in 3D
        page.goto(f"{url}/#/inspections/{compare['inspection_id']}")
        page.wait_for_selector("#scene-status:has-text('markers')")
        page.wait_for_selector("#defect-list:has-text('deviation')")
        page.screenshot(path=str(tmp_path / "compare-inspection.png"), full_page=True)
        # The inspection of perception runs only: its page asks for no measurement and
        # counts no panels.
        page = browser.new_page(viewport={"width": 1024, "height": 768})
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(url + "/")
        page.evaluate(f"sessionStorage.setItem('vista.token', {token!r})")
        page.goto(f"{url}/#/inspections/{inspection}")
        page.wait_for_selector("#perception-note:not([hidden])")
        assert page.locator("#defects-empty").is_hidden()
        page.wait_for_selector("#scene-status:has-text('no part measured here')")
        assert "measured panels" not in page.text_content("#scene-status")
        page.screenshot(path=str(tmp_path / "perception-inspection-1024.png"))
    assert errors == []
    _check_scenes(url, token, jobs, tmp_path)
    _check_headset_reads_the_scenes(url, inspection, jobs, tmp_path)


def _check_detection_pages(browser, url, token, inspection, jobs, errors, tmp_path) -> None:
    """A detection run: cars and scores per scan, the recall and precision against the
    labels; in 3D each scan with its boxes, as many as the scan had; with camera images,
    each image with its 2D boxes."""
    job = jobs["detect"]
    document = _output_json(url, token, job["id"], "detections.json")
    page = _open(browser, url, token, inspection, job, errors)
    page.wait_for_selector(".panel-plot[data-title='Cars per scan']")
    titles = page.locator(".panel").evaluate_all("(p) => p.map(x => x.dataset.title)")
    assert titles == ["Cars per scan", "Scores", "Detection"]
    counts = page.locator(".series[data-name='cars detected'] polyline").get_attribute("points")
    assert len(counts.split()) == 12
    assert "recall within 40 m" in page.text_content(".panel-figures")
    page.wait_for_selector("#scene-note:has-text('12 frames')")
    for frame in (0, 7):
        page.locator("#player-scrub").fill(str(frame))
        scan = document["scans"][frame]
        assert int(page.get_attribute("#job-scene canvas", "data-boxes")) == len(
            scan["boxes"]
        ) + len(scan["missed"])
    assert sum(len(s["boxes"]) for s in document["scans"]) > 0
    page.screenshot(path=str(tmp_path / "detect.png"), full_page=True)
    if "camera-detect" not in jobs:
        return
    page = _open(browser, url, token, inspection, jobs["camera-detect"], errors)
    _wait_for_pictures(page, 2, 4, 1241)  # at KITTI's size
    figures = page.text_content(".panel-figures")
    assert "unmeasured (the sequence has no labels" in figures and "time a scan" in figures
    page.wait_for_selector("#scene-note:has-text('2 frames')")
    page.screenshot(path=str(tmp_path / "camera-detect.png"), full_page=True)


def _wait_for_pictures(page, pictures: int, layers: int, wider_than: int) -> None:
    """The page's pictures drawn: ``pictures`` of them, ``layers`` images in all, each
    loaded and wider than ``wider_than`` pixels."""
    page.wait_for_selector(".picture")
    assert page.locator(".picture").count() == pictures
    wait_for(
        lambda: page.evaluate(
            "[...document.querySelectorAll('.picture img')]"
            f".every(i => i.complete && i.naturalWidth > {wider_than})"
        ),
        what="the pictures' images",
    )
    assert page.locator(".picture img").count() == layers


def _output_json(url: str, token: str, job_id: int, name: str) -> dict:
    view = httpx.get(f"{url}/api/v1/jobs/{job_id}/view", headers=auth(token), timeout=30).json()
    (artifact,) = [a for a in view["outputs"] if a["name"] == name]
    return httpx.get(
        f"{url}/api/v1/inspections/{artifact['inspection_id']}/artifacts/{artifact['id']}/content",
        headers=auth(token),
        timeout=30,
    ).json()


def _check_scenes(url: str, token: str, jobs: dict, tmp_path: Path) -> None:
    """Each result's glTF passes the Khronos validator and holds what it shows."""
    from tests.test_scene_export import validate

    http = httpx.Client(base_url=url, headers=auth(token), timeout=60)
    documents = {}
    for step in ("odometry", "track", "depth", "real-track", "detect", "camera-detect", "compare"):
        if step not in jobs:
            continue
        response = http.get(f"/api/v1/jobs/{jobs[step]['id']}/scene.glb", params={"points": 50_000})
        assert response.status_code == 200, response.text
        assert response.headers["content-type"] == "model/gltf-binary"
        path = tmp_path / f"{step}.glb"
        path.write_bytes(response.content)
        report = validate(path)
        assert report["issues"]["numErrors"] == 0, report["issues"]["messages"][:5]
        documents[step] = gltf_json(response.content)
    odometry = documents["odometry"]
    names = [n["name"] for n in odometry["nodes"]]
    assert names[0] == f"job-{jobs['odometry']['id']}" and "estimate" in names and "truth" in names
    estimate = next(n for n in odometry["nodes"] if n["name"] == "estimate")
    assert len(estimate["extras"]["sigma_xy_mm"]) == 19
    assert odometry["asset"]["extras"]["units"] == "metre"
    track = documents["track"]
    scans = [n for n in track["nodes"] if n["name"].startswith("scan-")]
    assert len(scans) == jobs["track"]["result"]["frames"] == 12
    (animation,) = track["animations"]
    paths = {(c["target"]["node"], c["target"]["path"]) for c in animation["channels"]}
    box = next(i for i, n in enumerate(track["nodes"]) if n["name"] == "tracked-box")
    assert {(box, "translation"), (box, "rotation")} <= paths
    assert any(n["name"] == "true-box" for n in track["nodes"])  # the drive has labels
    key_times = track["accessors"][animation["samplers"][-1]["input"]]
    assert key_times["count"] == 12 and key_times["max"] == [pytest.approx(1.1)]
    if "depth" in documents:
        clouds = [n for n in documents["depth"]["nodes"] if n["name"].startswith("cloud-")]
        assert len(clouds) == 2
    detect = documents["detect"]
    found = _output_json(url, token, jobs["detect"]["id"], "detections.json")["scans"]
    boxes = [n for n in detect["nodes"] if n["name"].startswith("detection-")]
    assert len(boxes) == sum(len(s["boxes"]) for s in found)
    assert {n["extras"]["verdict"] for n in boxes} <= {"found", "false", "unjudged"}
    assert all(0 <= n["extras"]["score"] <= 1 for n in boxes)
    wire = {n["mesh"] for n in detect["nodes"] if n["name"].startswith(("detection-", "missed-"))}
    assert len(wire) <= 4  # the boxes of one verdict share one mesh
    track_id = jobs["track"]["id"]
    for points in (2000, 3000):
        http.get(f"/api/v1/jobs/{track_id}/scene.glb", params={"points": points}).raise_for_status()
    cached = [p for p in tmp_path.rglob(f"job-{track_id}-*.glb") if "exports" in p.parts]
    assert len(cached) == 1  # the newest budget only: many budgets cannot fill the disk
    missing = http.get(f"/api/v1/jobs/{jobs['train']['id']}/scene.glb")
    assert missing.status_code == 404 and "no 3D scene" in missing.json()["detail"]
    http.close()


def gltf_json(glb: bytes) -> dict:
    import json
    import struct

    length, kind = struct.unpack_from("<II", glb, 12)
    assert kind == 0x4E4F534A
    return json.loads(glb[20 : 20 + length])


def _check_headset_reads_the_scenes(url: str, inspection: int, jobs: dict, tmp_path: Path) -> None:
    """The Unity client's protocol core (compiled by Mono, warnings as errors) lists the job
    scenes of a sync page, downloads each and reads its figures and animation."""
    import json
    import shutil
    import subprocess

    from tests.test_unity_client import CORE, NO_MONO, UNITY

    mcs, mono = shutil.which("mcs"), shutil.which("mono")
    if not (mcs and mono):
        pytest.fail(NO_MONO)
    exe = tmp_path / "scenes.exe"
    sources = [str(p) for p in sorted(CORE.glob("*.cs"))] + [
        str(UNITY / "Tests" / "JobScenesSmoke.cs")
    ]
    built = subprocess.run(
        [mcs, "-target:exe", f"-out:{exe}", "-r:System.Net.Http.dll", "-warnaserror", *sources],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert built.returncode == 0, built.stdout + built.stderr

    def listed(inspection_id: int) -> dict:
        done = subprocess.run(
            [mono, str(exe), url, "perception", "perception-pw", str(inspection_id)],
            capture_output=True, encoding="utf-8", timeout=60,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        return {s["job_id"]: s for s in json.loads(done.stdout.strip().splitlines()[-1])["scenes"]}

    scenes = listed(inspection)
    with_scenes = [j for step, j in jobs.items() if step not in ("train", "compare")]
    assert sorted(scenes) == sorted(j["id"] for j in with_scenes)
    compare = jobs["compare"]  # a comparison's scene: the coloured scan and the nominal
    compared = listed(compare["inspection_id"])[compare["id"]]
    assert compared["kind"] == "defects.compare" and "alignment" in compared["figures"]
    track = scenes[jobs["track"]["id"]]
    assert track["kind"] == "tracking.track" and track["units"] == "metre"
    assert track["root"] == f"job-{jobs['track']['id']}"
    assert track["box_keys"] == 12 and track["duration_s"] == pytest.approx(
        1.2, abs=1e-6
    )  # 12 frames
    assert track["frame_s"] == pytest.approx(0.1) and "frames" in track["figures"]
    odometry = scenes[jobs["odometry"]["id"]]
    assert odometry["box_keys"] == 0 and "method" in odometry["figures"]


def test_every_sample_run_is_accepted_as_it_is_declared(tmp_path):
    """The services' sample runs (what `vista bench clients` runs) at a tiny scale: each
    upload passes its artifact kind's check, each step names a known kind and its uploads."""
    from contract.kinds import load_hook
    from supervisor.engine.registry import artifact_kinds, declared_hooks, get_kind, load_kinds

    load_kinds()
    makers = declared_hooks("SAMPLE_RUN")
    assert {m.__module__ for m in makers} == {
        "services.odometry.sample",
        "services.depth.sample",
        "services.tracking.sample",
    }
    for maker in makers:
        sample = maker(tmp_path / maker.__module__, 3, None)
        for upload in sample.uploads.values():
            inspected = load_hook(artifact_kinds()[upload.kind].inspect)(
                upload.path, upload.media_type
            )
            assert inspected.media_type
        for step in sample.steps:
            assert get_kind(step.kind) is not None and set(step.inputs) <= set(sample.uploads)
            get_kind(step.kind).params.model_validate(step.params)
