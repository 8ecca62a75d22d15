"""The perception part of ``vista clients bench``: every service's sample run (its kinds'
``SAMPLE_RUN``, ``contract.samples``) on a live ``vista serve`` with its embedded engine,
then what a person waits for — each job's glTF scene (export seconds, MB, the Khronos
validator's verdict), each run page's first paint in headless Chromium at 1440 px (the
results drawn, the 3D scene drawn; screenshots kept beside the JSON) and, for a drive with
every point of its scans, the time to draw a frame and the frames shown in a second of
playing it at its 10 Hz.
"""

from __future__ import annotations

import json
import random
import statistics
import time
from pathlib import Path

import httpx

from benches.browser import launch_chromium
from benches.seeding import seed_database
from benches.server import running_server
from benches.validator import validate_gltf
from contract.bench import say
from supervisor.engine.registry import declared_hooks

JOB_TIMEOUT_S = 1800
FULL_POINTS = 20_000_000
"""The point budget that keeps every point of a drive's scans (the API's largest)."""


def run_perception_part(work: Path, shots: Path, *, frames: int, real_data: Path | None) -> dict:
    from supervisor.migrate import upgrade

    data = work / "perception-data"
    data.mkdir(parents=True)
    url = f"sqlite:///{data / 'vista.db'}"
    upgrade(url)
    seeded = seed_database(url, clients=1, defects=0, rng=random.Random(5))
    samples = []
    for maker in declared_hooks("SAMPLE_RUN"):
        say(f"making {maker.__module__}'s sample")
        samples.append(maker(work / maker.__module__, frames, real_data))
    shots.mkdir(parents=True, exist_ok=True)
    with running_server(
        data, url, api_workers=1, extra_env={"VISTA_EMBEDDED_WORKERS": "1"}
    ) as server:
        base = f"http://127.0.0.1:{server.port}"
        http = httpx.Client(
            base_url=base, headers={"Authorization": f"Bearer {seeded.admin_token}"}, timeout=600
        )
        jobs = []
        for sample in samples:
            say(f"running {sample.about}")
            jobs += _run(http, seeded.inspection_id, sample)
        results = []
        for job in jobs:
            row = {"step": job["step"], "kind": job["kind"], "job_id": job["id"]}
            view = http.get(f"/api/v1/jobs/{job['id']}/view").json()
            if view["scene"]:
                row["scene"] = _scene(http, job, work, validate_gltf)
            results.append(row)
        _pages(base, seeded.admin_token, seeded.inspection_id, results, shots)
        http.close()
    return {"samples": [s.about for s in samples], "jobs": results}


def _run(http: httpx.Client, inspection: int, sample) -> list[dict]:  # noqa: ANN001
    ids = {}
    for label, upload in sample.uploads.items():
        answer = http.post(
            f"/api/v1/inspections/{inspection}/artifacts",
            params={"kind": upload.kind, "name": upload.path.name},
            content=upload.path.read_bytes(),
            headers={"content-type": upload.media_type},
        )
        answer.raise_for_status()
        ids[label] = answer.json()["id"]
    steps = [
        {
            "name": s.name,
            "kind": s.kind,
            "inputs": [ids[i] for i in s.inputs],
            "params": s.params,
            "after": list(s.after),
        }
        for s in sample.steps
    ]
    run = http.post(f"/api/v1/inspections/{inspection}/runs", json={"steps": steps})
    run.raise_for_status()
    finished = []
    for job in run.json()["jobs"]:
        deadline = time.monotonic() + JOB_TIMEOUT_S
        while (state := http.get(f"/api/v1/jobs/{job['id']}").json())["status"] not in (
            "succeeded",
            "failed",
            "cancelled",
        ):
            if time.monotonic() > deadline:
                raise RuntimeError(f"job {job['id']} ({job['kind']}) did not finish in time")
            time.sleep(0.5)
        if state["status"] != "succeeded":
            raise RuntimeError(
                f"job {job['id']} ({job['kind']}) {state['status']}: {state['error']}"
            )
        finished.append(state)
    return finished


def _scene(http: httpx.Client, job: dict, work: Path, validate) -> dict:  # noqa: ANN001
    """The scene at the server's default point budget, cold then cached, and with every
    point of a drive's scans."""
    out = {}
    for label, points in (("default", None), ("every point", FULL_POINTS)):
        params = {"points": points} if points else {}
        started = time.perf_counter()
        answer = http.get(f"/api/v1/jobs/{job['id']}/scene.glb", params=params)
        cold_s = time.perf_counter() - started
        answer.raise_for_status()
        started = time.perf_counter()
        http.get(f"/api/v1/jobs/{job['id']}/scene.glb", params=params).raise_for_status()
        cached_s = time.perf_counter() - started
        path = work / f"job-{job['id']}-{label.replace(' ', '-')}.glb"
        path.write_bytes(answer.content)
        out[label] = {
            "export_s": round(cold_s, 3),
            "cached_s": round(cached_s, 4),
            "mb": round(len(answer.content) / 1e6, 2),
            "validator": validate(path),
        }
    return out


def _pages(base: str, token: str, inspection: int, results: list[dict], shots: Path) -> None:
    """Each job's run page: when its results and its scene are first drawn (median of three
    loads, the first a cold cache), a screenshot; a drive's player drawing every point."""
    with launch_chromium() as browser:
        for row in results:
            loads = [_load(browser, base, token, inspection, row) for _ in range(3)]
            row["page"] = {
                "panels_s": statistics.median(load["panels_s"] for load in loads),
                "cold_panels_s": loads[0]["panels_s"],
            }
            if "scene" in row:
                row["page"]["scene_s"] = statistics.median(load["scene_s"] for load in loads)
            page = _open(browser, base, token, inspection, row)
            page.screenshot(path=str(shots / f"run-{row['step']}.png"), full_page=True)
            row["page"]["screenshot"] = str(shots / f"run-{row['step']}.png")
            page.context.close()
            if row["kind"] == "tracking.track":
                row["player"] = _player(browser, base, token, inspection, row)
                say(f"{row['step']}: {json.dumps(row['player'])}")


def _open(browser, base: str, token: str, inspection: int, row: dict, points: int | None = None):  # noqa: ANN001, ANN202
    context = browser.new_context(viewport={"width": 1440, "height": 1000})
    context.add_init_script(f"sessionStorage.setItem('vista.token', {json.dumps(token)})")
    page = context.new_page()
    suffix = f"?points={points}" if points else ""
    page.goto(f"{base}/#/inspections/{inspection}/jobs/{row['job_id']}{suffix}")
    marks = ["vista:job-panels", *(["vista:job-scene"] if "scene" in row else [])]
    for mark in marks:
        page.wait_for_function(
            f"() => performance.getEntriesByName('{mark}').length > 0", timeout=300_000
        )
    return page


def _load(browser, base: str, token: str, inspection: int, row: dict) -> dict:  # noqa: ANN001
    page = _open(browser, base, token, inspection, row)
    marks = page.evaluate(
        "() => Object.fromEntries(performance.getEntriesByType('mark').map(m => [m.name, m.startTime]))"
    )
    page.context.close()
    return {
        "panels_s": round(marks["vista:job-panels"] / 1000, 3),
        "scene_s": round(marks.get("vista:job-scene", 0) / 1000, 3),
    }


def _player(browser, base: str, token: str, inspection: int, row: dict) -> dict:  # noqa: ANN001
    """The drive with every point: the frames drawn in a second of playing it at its 10 Hz.
    (A draw's own time is not measured: with the software GL of a headless Chromium,
    ``render`` + ``gl.finish`` took about 1 ms for 46 000 and 116 000 points alike.)"""
    page = _open(browser, base, token, inspection, row, points=FULL_POINTS)
    frames = int(page.get_attribute("#player-scrub", "max")) + 1
    page.locator("#player-scrub").fill(str(frames // 2))
    points = page.get_attribute("#job-scene canvas", "data-points")
    page.click("#player-play")
    page.wait_for_timeout(PLAY_S * 1000)
    shown = int(page.get_attribute("#job-scene canvas", "data-shown-per-s") or 0)
    page.click("#player-play")
    page.context.close()
    return {
        "frames": frames,
        "points_per_frame": int(points) if points else None,
        "frames_per_s_played": shown,
    }


PAINT_TARGET_S = 2.0
PLAYED_TARGET = 9
"""Frames shown in a second of playing a 10 Hz drive (one may fall across the second's edge)."""
PLAY_S = 4
"""How long a drive plays before the frames of its last second are counted."""


def perception_verdict(part: dict) -> dict:
    rows = part["jobs"]
    scenes = [r["scene"][k] for r in rows if "scene" in r for k in r["scene"]]
    players = [r["player"] for r in rows if "player" in r]
    return {
        "every job scene: validator 0 errors": all(
            s["validator"]["numErrors"] == 0 for s in scenes
        ),
        f"every run page's results drawn < {PAINT_TARGET_S} s": all(
            r["page"]["panels_s"] < PAINT_TARGET_S for r in rows
        ),
        "a drive plays at 10 frames a second with every point": bool(players)
        and all(p["frames_per_s_played"] >= PLAYED_TARGET for p in players),
    }


def print_perception(part: dict) -> None:
    print("\n## Perception results (each service's sample run)\n")
    for about in part["samples"]:
        print(f"- {about}")
    print("\n| job | kind | scene | export s (cold) | cached s | MB | validator e/w/i |")
    print("|---|---|---|---|---|---|---|")
    for row in part["jobs"]:
        for label, scene in row.get("scene", {}).items():
            v = scene["validator"]
            print(
                f"| {row['step']} | {row['kind']} | {label} | {scene['export_s']:.3f} | "
                f"{scene['cached_s']:.4f} | {scene['mb']:.1f} | "
                f"{v['numErrors']} / {v['numWarnings']} / {v['numInfos']} |"
            )
    print("\n| run page | results drawn s (median of 3) | cold s | 3D drawn s | screenshot |")
    print("|---|---|---|---|---|")
    for row in part["jobs"]:
        page = row["page"]
        scene_s = f"{page['scene_s']:.3f}" if "scene_s" in page else "–"
        print(
            f"| {row['step']} ({row['kind']}) | {page['panels_s']:.3f} | "
            f"{page['cold_panels_s']:.3f} | {scene_s} | {Path(page['screenshot']).name} |"
        )
    players = [(r["step"], r["player"]) for r in part["jobs"] if "player" in r]
    if players:
        print(
            "\n| drive, every point | frames | points a frame "
            "| frames drawn in a second of playing (a 10 Hz drive needs 10) |"
        )
        print("|---|---|---|---|")
        for step, p in players:
            print(
                f"| {step} | {p['frames']} | {p['points_per_frame']} | {p['frames_per_s_played']} |"
            )
