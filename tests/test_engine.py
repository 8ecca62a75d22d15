"""The job engine end to end, on both engines: embedded (SQLite, worker processes beside
the API) and Dramatiq (PostgreSQL + Redis, separate `vista worker` processes)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import redis

from services.lib.pointcloud.ply import validate_ply, write_ply
from supervisor.engine.runner import run_job, sentence
from tests.conftest import (
    BROKER_URL,
    NO_BROKER,
    NO_POSTGRES,
    add_user,
    auth,
    make_settings,
    wait_for,
)
from tests.plyfiles import plane_grid, ply_bytes

REPO = Path(__file__).resolve().parent.parent
TERMINAL = ("succeeded", "failed", "cancelled")


class Engine:
    """A live supervisor plus whatever runs its jobs, and an HTTP client for it."""

    def __init__(self, kind, tmp_path, request, start_server, **overrides):
        self.kind = kind
        self.tmp_path = tmp_path
        self.workers: list[subprocess.Popen] = []
        if kind == "embedded":
            url = request.getfixturevalue("sqlite_url")
            self.settings = make_settings(tmp_path, url, embedded_workers=1, **overrides)
        else:
            url = request.getfixturevalue("postgres_url")
            redis.Redis.from_url(BROKER_URL).flushdb()
            self.settings = make_settings(tmp_path, url, broker_url=BROKER_URL, **overrides)
        self.server = start_server(self.settings)
        self.runtime = self.server.app.state.runtime
        self.token = add_user(self.runtime, "op", "inspector", "operator-password")
        self.http = httpx.Client(base_url=self.server.url, headers=auth(self.token), timeout=30)
        self.inspection = self.http.post(
            "/api/v1/inspections", json={"title": "engine", "area": "component"}
        ).json()["id"]
        if kind == "dramatiq":
            self.start_worker()

    def start_worker(self) -> None:
        s = self.settings
        env = {
            **os.environ,
            "PYTHONPATH": str(REPO),
            "VISTA_DATABASE_URL": s.database_url,
            "VISTA_BROKER_URL": s.broker_url,
            "VISTA_DATA_DIR": str(s.data_dir),
            "VISTA_ARTIFACT_DIR": str(s.resolved_artifact_dir),
            "VISTA_EXTRA_JOB_KINDS": "tests.jobkinds",
            "VISTA_HEARTBEAT_INTERVAL_S": str(s.heartbeat_interval_s),
            "VISTA_HEARTBEAT_TIMEOUT_S": str(s.heartbeat_timeout_s),
            "VISTA_RETRY_BACKOFF_S": str(s.retry_backoff_s),
            "VISTA_JOB_MAX_ATTEMPTS": str(s.job_max_attempts),
            "VISTA_JOB_MEMORY_MB": str(s.job_memory_mb),
        }
        log = open(self.tmp_path / f"worker-{len(self.workers)}.log", "wb")  # noqa: SIM115
        self.workers.append(
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "supervisor.cli",
                    "worker",
                    "--queues",
                    "scan,stitching,defects,odometry,depth,tracking,training,test",
                ],
                env=env,
                cwd=REPO,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        )

    def close(self) -> None:
        self.http.close()
        for worker in self.workers:
            if worker.poll() is None:
                worker.send_signal(signal.SIGTERM)
                try:
                    worker.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    worker.kill()

    def run(self, steps: list[dict]) -> dict:
        response = self.http.post(
            f"/api/v1/inspections/{self.inspection}/runs", json={"steps": steps}
        )
        assert response.status_code == 201, response.text
        return response.json()

    def job(self, job_id: int) -> dict:
        return self.http.get(f"/api/v1/jobs/{job_id}").json()

    def wait(self, job_id: int, statuses=TERMINAL, timeout: float = 60) -> dict:
        return wait_for(
            lambda: (j := self.job(job_id))["status"] in statuses and j,
            timeout=timeout,
            what=f"job {job_id} to reach {statuses}",
        )


@pytest.fixture(params=["embedded", "dramatiq"])
def engine_factory(request, tmp_path, start_server):
    if request.param == "dramatiq" and not BROKER_URL:
        pytest.skip(NO_BROKER)
    if request.param == "dramatiq" and not os.environ.get("VISTA_TEST_DATABASE_URL"):
        pytest.skip(NO_POSTGRES)
    yield from _engines(request.param, request, tmp_path, start_server)


@pytest.fixture
def embedded_engine_factory(request, tmp_path, start_server):
    """The embedded engine alone: for a service's learned jobs, whose handlers run alike on
    either engine (the transport is tested on both by the other tests) and which train."""
    yield from _engines("embedded", request, tmp_path, start_server)


def _engines(kind: str, request, tmp_path, start_server):
    made: list[Engine] = []

    def make(**overrides) -> Engine:
        engine = Engine(kind, tmp_path, request, start_server, **overrides)
        made.append(engine)
        return engine

    yield make
    for engine in made:
        engine.close()


def sleep_step(name: str, after=(), **params) -> dict:
    return {"name": name, "kind": "test.sleep", "params": params, "after": list(after)}


def test_scan_inspect_produces_report_and_preview(engine_factory, tmp_path):
    engine = engine_factory()
    data = ply_bytes(tmp_path, plane_grid(300, 400, spacing_mm=0.1))
    scan = engine.http.post(
        f"/api/v1/inspections/{engine.inspection}/artifacts",
        params={"kind": "scan", "name": "scan_000.ply"},
        content=data,
        headers={"content-type": "application/x-ply"},
    ).json()
    run = engine.run(
        [
            {
                "name": "inspect",
                "kind": "scan.inspect",
                "inputs": [scan["id"]],
                "params": {"preview_points": 10_000},
            }
        ]
    )
    job = engine.wait(run["jobs"][0]["id"])
    assert job["status"] == "succeeded", job
    report = job["result"]["reports"][str(scan["id"])]
    assert report["point_count"] == 120_000 and report["all_finite"]
    assert report["mean_spacing_mm"] == pytest.approx(0.1, rel=1e-3)
    artifacts = engine.http.get(f"/api/v1/inspections/{engine.inspection}/artifacts").json()[
        "items"
    ]
    by_kind = {a["kind"]: a for a in artifacts if a["job_id"] == job["id"]}
    assert set(by_kind) == {"report", "preview"}
    base = f"/api/v1/inspections/{engine.inspection}/artifacts"
    stored = json.loads(engine.http.get(f"{base}/{by_kind['report']['id']}/content").content)
    assert stored["point_count"] == 120_000
    preview = tmp_path / "preview.ply"
    preview.write_bytes(engine.http.get(f"{base}/{by_kind['preview']['id']}/content").content)
    assert 5_000 <= validate_ply(preview).vertex_count <= 10_000
    assert run_job(job["id"], runtime=engine.runtime) == "skipped"  # re-running is a no-op


def test_dependencies_run_in_order_and_pass_outputs(engine_factory):
    engine = engine_factory()
    status = lambda: engine.http.get(f"/api/v1/inspections/{engine.inspection}").json()["status"]  # noqa: E731
    assert status() == "planned"
    run = engine.run([sleep_step("first", seconds=1.0), sleep_step("second", after=["first"])])
    assert status() == "processing"  # the inspection's status follows its runs
    first, second = (j["id"] for j in run["jobs"])
    assert engine.job(second)["status"] == "waiting" and engine.job(second)["depends_on"] == [first]
    done = engine.wait(second)
    assert done["status"] == "succeeded"
    first_outputs = [
        a["id"]
        for a in engine.http.get(f"/api/v1/inspections/{engine.inspection}/artifacts").json()[
            "items"
        ]
        if a["job_id"] == first
    ]
    assert done["result"]["inputs"] == first_outputs and len(first_outputs) == 1
    assert engine.job(first)["finished_at"] <= done["started_at"]
    assert engine.http.get(f"/api/v1/runs/{run['id']}").json()["status"] == "succeeded"
    assert status() == "review"


def test_failure_cancels_what_depends_on_it(engine_factory):
    engine = engine_factory()
    run = engine.run(
        [
            sleep_step("measure", fail_with="the cloud is empty"),
            sleep_step("export", after=["measure"]),
        ]
    )
    failed = engine.wait(run["jobs"][0]["id"])
    assert failed["status"] == "failed" and "ValueError: the cloud is empty" in failed["error"]
    # one sentence for people; the traceback went to the worker's log
    assert "\n" not in failed["error"] and "Traceback" not in failed["error"]
    assert f"under job {failed['id']}." in failed["error"]
    assert failed["attempts"] == 1  # a permanent error is not retried
    export = engine.wait(run["jobs"][1]["id"])
    assert export["status"] == "cancelled" and "measure" in export["message"]
    assert engine.http.get(f"/api/v1/runs/{run['id']}").json()["status"] == "failed"


def test_transient_errors_are_retried_with_backoff(engine_factory):
    engine = engine_factory()
    run = engine.run(
        [
            sleep_step("flaky", seconds=0.1, transient_failures=2),
            sleep_step("hopeless", seconds=0.1, transient_failures=9),
        ]
    )
    flaky = engine.wait(run["jobs"][0]["id"])
    assert (
        flaky["status"] == "succeeded"
        and flaky["attempts"] == 3
        and flaky["result"]["attempt"] == 3
    )
    hopeless = engine.wait(run["jobs"][1]["id"])
    assert hopeless["status"] == "failed" and hopeless["attempts"] == 3
    assert "simulated outage in attempt 3" in hopeless["error"]


def test_cancel_reaches_a_running_job_and_retry_runs_it_again(engine_factory):
    engine = engine_factory()
    run = engine.run(
        [sleep_step("long", seconds=30), sleep_step("after", after=["long"], seconds=0.1)]
    )
    long_id, after_id = (j["id"] for j in run["jobs"])
    engine.wait(long_id, statuses=("running",))
    assert engine.http.post(f"/api/v1/jobs/{long_id}/cancel").json()["cancel_requested"]
    cancelled = engine.wait(long_id, timeout=10)
    assert cancelled["status"] == "cancelled" and cancelled["progress"] < 0.5
    assert engine.job(after_id)["status"] == "cancelled"
    assert engine.http.post(f"/api/v1/jobs/{after_id}/cancel").status_code == 409
    retried = engine.http.post(f"/api/v1/jobs/{long_id}/retry")
    assert retried.status_code == 200 and retried.json()["status"] == "queued"
    assert engine.job(after_id)["status"] == "waiting"
    engine.wait(long_id, statuses=("running",))
    engine.http.post(f"/api/v1/jobs/{long_id}/cancel")
    assert engine.wait(long_id, timeout=10)["status"] == "cancelled"


def test_a_job_beyond_the_workers_memory_fails_with_a_sentence_and_is_not_retried(
    engine_factory,
):
    """A job that asks for more memory than a worker's address space: MemoryError where it
    allocates, one sentence with the limit, no second attempt (a job the kernel's OOM
    killer ended was retried twice, to meet the same end)."""
    engine = engine_factory(job_memory_mb=3072)
    job_id = engine.run([sleep_step("greedy", seconds=0.1, allocate_mb=8192)])["jobs"][0]["id"]
    failed = engine.wait(job_id, timeout=90)
    assert failed["status"] == "failed" and failed["attempts"] == 1, failed
    assert "more memory than a worker allows" in failed["error"], failed["error"]
    assert "3.0 GiB" in failed["error"] and "8.00 GiB" in failed["error"], failed["error"]
    ok = engine.run([sleep_step("modest", seconds=0.1, allocate_mb=64)])["jobs"][0]["id"]
    assert engine.wait(ok, timeout=90)["status"] == "succeeded"  # the worker lives on


def _kill_worker_running(engine: Engine, job_id: int) -> None:
    job = wait_for(
        lambda: (j := engine.job(job_id))["status"] == "running" and j["progress"] > 0 and j,
        what="the job to make progress",
    )
    pid = int(job["worker"].rsplit(":", 1)[1])
    os.kill(pid, signal.SIGKILL)
    if engine.kind == "dramatiq":  # `vista worker` exits when a child dies; compose restarts it
        engine.workers[-1].wait(timeout=30)
        engine.start_worker()


def test_a_cancel_outlives_the_worker_that_was_asked(engine_factory):
    """Cancel a running job whose worker is frozen (it cannot see the request), then kill
    the worker: the job ends cancelled, not re-queued to run to "succeeded" (the flag was
    cleared when it was re-queued)."""
    engine = engine_factory()
    job_id = engine.run([sleep_step("victim", seconds=20.0)])["jobs"][0]["id"]
    job = wait_for(
        lambda: (j := engine.job(job_id))["status"] == "running" and j["progress"] > 0 and j,
        what="the job to make progress",
    )
    pid = int(job["worker"].rsplit(":", 1)[1])
    try:
        for _ in range(20):
            os.kill(pid, signal.SIGSTOP)
            try:
                answer = engine.http.post(f"/api/v1/jobs/{job_id}/cancel", timeout=10)
                break
            except httpx.TimeoutException:
                # frozen inside a write (a progress or heartbeat transaction holds the job's
                # row): let it finish that write, then freeze it again
                os.kill(pid, signal.SIGCONT)
                time.sleep(0.05)
        assert answer.json()["cancel_requested"]
    finally:
        os.kill(pid, signal.SIGKILL)
    if engine.kind == "dramatiq":
        engine.workers[-1].wait(timeout=30)
        engine.start_worker()
    ended = engine.wait(job_id, timeout=90)
    assert ended["status"] == "cancelled" and ended["attempts"] == 1, ended


def test_killed_worker_job_runs_again(engine_factory):
    engine = engine_factory()
    job_id = engine.run([sleep_step("victim", seconds=2.0)])["jobs"][0]["id"]
    _kill_worker_running(engine, job_id)
    done = engine.wait(job_id, timeout=90)
    assert done["status"] == "succeeded" and done["attempts"] == 2
    assert done["result"]["attempt"] == 2


def test_killed_worker_without_attempts_left_fails_with_a_reason(engine_factory):
    engine = engine_factory(job_max_attempts=1)
    job_id = engine.run([sleep_step("victim", seconds=5.0)])["jobs"][0]["id"]
    _kill_worker_running(engine, job_id)
    failed = engine.wait(job_id, timeout=90)
    assert failed["status"] == "failed"
    if engine.kind == "embedded":  # the pool sees its worker exit: no wait for the heartbeat
        assert "exited (exit code -9, killed by SIGKILL) in attempt 1 of 1" in failed["error"]
    else:
        assert "lost: no heartbeat for 3 s in attempt 1 of 1" in failed["error"]


def test_progress_streams_as_server_sent_events(engine_factory):
    engine = engine_factory()
    job_id = engine.run([sleep_step("watched", seconds=1.5)])["jobs"][0]["id"]
    events = []
    with engine.http.stream("GET", f"/api/v1/jobs/{job_id}/events", timeout=60) as response:
        assert response.headers["content-type"].startswith("text/event-stream")
        event = None
        for line in response.iter_lines():
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                events.append((event, json.loads(line[6:])))
                if event == "end":
                    break
    progress = [data["progress"] for name, data in events if name == "progress"]
    assert len(progress) >= 3 and progress == sorted(progress)
    assert events[-1] == ("end", {"status": "succeeded"})


def _upload(engine: Engine, path: Path, kind: str, media_type: str) -> int:
    response = engine.http.post(
        f"/api/v1/inspections/{engine.inspection}/artifacts",
        params={"kind": kind, "name": path.name},
        content=path.read_bytes(),
        headers={"content-type": media_type},
    )
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _upload_session(engine: Engine, example: Path) -> tuple[int, int, list[int]]:
    """pairs.json, scans.json and the scan PLYs of a simulated example: their ids."""
    pairs = _upload(engine, example / "pairs.json", "pairs", "application/json")
    manifest = _upload(engine, example / "scans.json", "scans", "application/json")
    scans = [
        _upload(engine, path, "scan", "application/x-ply")
        for path in sorted(example.glob("scan_*.ply"))
    ]
    return pairs, manifest, scans


def _calibrate_stitch(pairs: int, manifest: int, scans: list[int], params=None) -> list[dict]:
    """The steps of a calibrate → stitch run."""
    stitch = {"name": "stitch", "kind": "stitching.stitch", "inputs": [manifest, *scans]}
    return [
        {"name": "calibrate", "kind": "stitching.calibrate", "inputs": [pairs]},
        {**stitch, "after": ["calibrate"], "params": params or {}},
    ]


def test_calibrate_then_stitch_in_one_run(engine_factory, tmp_path):
    from typer.testing import CliRunner

    from supervisor.cli import app

    example = tmp_path / "example"
    simulated = CliRunner().invoke(app, ["simulate", "stitching", str(example), "--corrupt", "1"])
    assert simulated.exit_code == 0, simulated.output
    engine = engine_factory()
    pairs, manifest, scans = _upload_session(engine, example)
    run = engine.run(_calibrate_stitch(pairs, manifest, scans, {"icp": "bounded"}))
    calibrate_job, stitch_job = (engine.wait(j["id"], timeout=120) for j in run["jobs"])
    assert calibrate_job["status"] == "succeeded", calibrate_job
    truth = json.loads((example / "truth.json").read_text())
    assert calibrate_job["result"]["dropped_pairs"] == truth["corrupted_pairs"]
    assert stitch_job["status"] == "succeeded", stitch_job
    assert stitch_job["result"]["calibration_method"] == "vista"
    assert stitch_job["result"]["overlap_mean_mm"] < 0.3
    base = f"/api/v1/inspections/{engine.inspection}/artifacts"
    produced = {
        a["kind"]: a
        for a in engine.http.get(base, params={"limit": 100}).json()["items"]
        if a["job_id"] in (calibrate_job["id"], stitch_job["id"])
    }
    assert set(produced) == {"handeye", "cloud", "report", "plot"}
    report = json.loads(engine.http.get(f"{base}/{produced['report']['id']}/content").content)
    assert report["icp"]["method"] == "bounded" and report["points"] > 100_000
    cloud = tmp_path / "stitched.ply"
    cloud.write_bytes(engine.http.get(f"{base}/{produced['cloud']['id']}/content").content)
    assert validate_ply(cloud).vertex_count == report["points"]
    # its run page: a kind that declares no view shows its result's figures
    page = engine.http.get(f"/api/v1/jobs/{stitch_job['id']}/view").json()
    (result,) = page["panels"]
    assert result["type"] == "figures" and result["title"] == "Result"
    shown = {f["label"]: f["value"] for f in result["figures"]}
    assert shown["overlap_mean_mm"] == stitch_job["result"]["overlap_mean_mm"]
    assert "declares no view" in page["note"] and len(page["outputs"]) == 3

    # A stitch without a calibration is refused when the run is created, naming what is missing.
    lonely = engine.http.post(
        f"/api/v1/inspections/{engine.inspection}/runs",
        json={
            "steps": [{"name": "stitch", "kind": "stitching.stitch", "inputs": [manifest, *scans]}]
        },
    )
    assert lonely.status_code == 422 and "exactly 1 'handeye'" in lonely.json()["detail"]


def _seen_depth_mm(scratch: dict, *, spacing_mm: float) -> float:
    """A scratch's depth as a scan of that spacing sees it (see the test below)."""
    return scratch["depth_mm"] * min(1.0, scratch["width_mm"] / spacing_mm)


def test_calibrate_stitch_measure_fills_the_defect_list(engine_factory, tmp_path):
    from typer.testing import CliRunner

    from supervisor.cli import app

    example = tmp_path / "assembly"
    simulated = CliRunner().invoke(
        app, ["simulate", "defects", str(example), "--spacing-mm", "0.25", "--seed", "3"]
    )
    assert simulated.exit_code == 0, simulated.output
    engine = engine_factory()
    tolerances = {"gap_mm": {"min": 0.5, "max": 3.0}, "step_mm": {"max": 1.2}}
    patched = engine.http.patch(
        f"/api/v1/inspections/{engine.inspection}", json={"tolerances": tolerances}
    )
    assert patched.status_code == 200, patched.text
    pairs, manifest, scans = _upload_session(engine, example)
    run = engine.run(
        [
            *_calibrate_stitch(pairs, manifest, scans),
            {"name": "measure", "kind": "defects.measure", "after": ["stitch"]},
        ]
    )
    jobs = [engine.wait(j["id"], timeout=180) for j in run["jobs"]]
    assert [j["status"] for j in jobs] == ["succeeded"] * 3, jobs
    measured = jobs[2]["result"]
    assert measured["seams"] == 4 and measured["junctions"] == 1 and measured["panels"] == 4
    defects = engine.http.get(
        "/api/v1/defects", params={"inspection": engine.inspection, "run": run["id"], "limit": 200}
    ).json()["items"]
    truth = json.loads((example / "truth.json").read_text())
    found = [d for d in defects if d["tolerance_state"] == "out"]
    assert len(found) == measured["defects"]
    unsure = [d for d in defects if d["tolerance_state"] == "uncertain"]
    assert len(unsure) == measured["uncertain"]
    assert all(d["measurements"]["advice"] and d["measurements"]["sigma_mm"] > 0 for d in unsure)
    # every true step over 1.2 mm and every surface defect is on the list
    big_steps = [s for s in truth["seams"] if abs(s["step_mm"]) > 1.2]
    assert len([d for d in found if d["type"] == "step"]) == len(big_steps)
    # A defect of its type lies within the true one's reach (on a 0.25 mm scan a shallow
    # scratch may be found in pieces, or a piece within tolerance: the cells' phase). A
    # groove narrower than the scan's spacing is hit by a fraction width/spacing of the
    # samples across it, so what the scan sees of its depth shrinks by that fraction; a
    # scratch is required only where that is still 1.5 × the 0.1 mm tolerance (one found at
    # 0.177 × 0.176 mm came and went with the CPU's vector width, AVX2 against AVX-512).
    for true in truth["defects"]:
        reach = max(true.get("length_mm", 0.0), true.get("diameter_mm", 0.0))
        near = [
            d
            for d in found
            if d["type"] == true["type"]
            and math.dist(d["location_mm"], true["location"]) <= reach / 2 + 3.0
        ]
        if true["type"] != "scratch" or _seen_depth_mm(true, spacing_mm=0.25) >= 1.5 * 0.1:
            assert near, true
    for kind in ("dent", "bump", "scratch", "color"):
        expected = [d for d in truth["defects"] if d["type"] == kind]
        assert len([d for d in found if d["type"] == kind]) <= 2 * len(expected), kind
    # seams within tolerance stay as measurements, with their profile
    flagged = {d["measurements"]["seam"] for d in found + unsure if "seam" in d["measurements"]}
    info = [d for d in defects if d["tolerance_state"] == "within"]
    assert len(info) == 4 - len(flagged)
    assert all(d["type"] == "gap" and "gap_mm" in d["measurements"] for d in info)
    colour = next(d for d in found if d["type"] == "color")
    assert colour["value_mm"] is None and colour["measurements"]["unit"] == "delta_e"
    _check_findings_follow_the_tolerances(engine, run, defects, tolerances)
    base = f"/api/v1/inspections/{engine.inspection}/artifacts"
    produced = {
        a["name"]
        for a in engine.http.get(base, params={"limit": 100}).json()["items"]
        if a["job_id"] == jobs[2]["id"]
    }
    assert produced == {"defects.json", "seam-profiles.png"}

    # A cloud that holds no panel assembly fails the job with the reason, storing nothing.
    from services.lib.pointcloud.ply import PointCloud

    spray = tmp_path / "spray.ply"
    points = np.random.default_rng(0).uniform(0, 50, (5000, 3)).astype(np.float32)
    write_ply(spray, PointCloud(points=points))
    cloud = _upload(engine, spray, "cloud", "application/x-ply")
    lonely = engine.run([{"name": "measure", "kind": "defects.measure", "inputs": [cloud]}])
    failed = engine.wait(lonely["jobs"][0]["id"])
    assert failed["status"] == "failed" and "no panel top" in failed["error"]
    assert engine.http.get("/api/v1/defects", params={"run": lonely["id"]}).json()["items"] == []
    _check_each_run_shows_its_own_scene(engine, run, defects, tmp_path)


def _check_findings_follow_the_tolerances(engine: Engine, run: dict, defects: list, tolerances):
    """The rule that judges a stored finding again is measure's own (each finding judged
    again by it against the limits it was measured with is as measure stored it); widening
    the gaps' range to 0.3–6 mm turns every gap within it into a measurement in the same
    request, seen by the sync; the old range brings the old judgments back."""
    from contract.tolerances import Tolerances, judge, limits_of

    def judged_again(limits_doc: dict) -> list[tuple]:
        limits = limits_of(Tolerances.model_validate(limits_doc))
        out = []
        for d in defects:
            m = d["measurements"]
            j = judge(d["type"], m["value"], limits, m.get("gap_range_mm"))
            out.append((d["id"], j.severity, j.limit))
        return out

    assert judged_again(tolerances) == [
        (d["id"], d["severity"], d["measurements"]["tolerance"]) for d in defects
    ]
    base = f"/api/v1/inspections/{engine.inspection}"
    since = engine.http.get("/api/v1/sync", params={"inspection": engine.inspection}).json()
    wider = {**tolerances, "gap_mm": {"min": 0.3, "max": 6.0}}
    assert engine.http.patch(base, json={"tolerances": wider}).status_code == 200
    now = engine.http.get(
        "/api/v1/defects", params={"inspection": engine.inspection, "run": run["id"], "limit": 200}
    ).json()["items"]
    gaps = [d for d in now if d["type"] == "gap"]
    inside = [
        0.3 <= d["measurements"]["gap_range_mm"][0] <= d["measurements"]["gap_range_mm"][1] <= 6
        for d in gaps
    ]
    assert any(inside) and [d["severity"] == "info" for d in gaps] == inside
    assert all(d["measurements"]["tolerance"] == d["tolerance_mm"] for d in gaps)
    for d in (d for d, within in zip(gaps, inside, strict=True) if within):
        # judged by its widest gap now (its narrowest was out) unless its narrowest lies
        # within 2σ of the new minimum: the finding is where the end it is judged by is
        ends, at = d["measurements"]["gap_range_mm"], d["measurements"]["gap_range_at_mm"]
        end = ends.index(d["value_mm"])
        assert d["location_mm"] == at[end]
        assert end == 1 or d["tolerance_state"] == "uncertain"
        assert d["tolerance_state"] != "out" and d["tolerance_mm"] == (0.3, 6.0)[end]
    assert [(d["id"], d["severity"]) for d in now if d["type"] != "gap"] == [
        (d["id"], d["severity"]) for d in defects if d["type"] != "gap"
    ]
    synced = engine.http.get(
        "/api/v1/sync", params={"inspection": engine.inspection, "since": since["next_cursor"]}
    ).json()
    assert {d["id"] for d in synced["defects"]} >= {
        d["id"] for d in defects if d["type"] == "gap" and d["severity"] != "info"
    }
    assert engine.http.patch(base, json={"tolerances": tolerances}).status_code == 200
    again = engine.http.get(
        "/api/v1/defects", params={"inspection": engine.inspection, "run": run["id"], "limit": 200}
    ).json()["items"]
    assert [
        (d["id"], d["severity"], d["tolerance_mm"], d["value_mm"], d["location_mm"]) for d in again
    ] == [
        (d["id"], d["severity"], d["tolerance_mm"], d["value_mm"], d["location_mm"])
        for d in defects
    ]


def _check_each_run_shows_its_own_scene(engine: Engine, first: dict, defects: list, tmp_path):
    """A second cloud, a flat plate, measured after the assembly: the inspection's scene is
    the plate's run (its cloud, its one panel, none of the assembly's rings), the
    assembly's run keeps its own scene, and deleting the plate's cloud brings the
    assembly's back — not the spray whose measurement failed."""
    from tests.test_run_pages import gltf_json

    plate_path = tmp_path / "plate.ply"
    write_ply(plate_path, plane_grid(400, 400, spacing_mm=0.5))
    plate = _upload(engine, plate_path, "cloud", "application/x-ply")
    second = engine.run([{"name": "measure", "kind": "defects.measure", "inputs": [plate]}])
    plate_job = engine.wait(second["jobs"][0]["id"])
    assert plate_job["status"] == "succeeded"
    # one panel, no seam: not a plain "done", since nothing of a seam was judged
    assert plate_job["warning"].startswith("no seam found (1 panel told apart)")
    base = f"/api/v1/inspections/{engine.inspection}"
    runs = engine.http.get(f"{base}/scene-runs").json()
    assert [r["run_id"] for r in runs] == [second["id"], first["id"]]  # not the failed spray
    assert runs[0]["cloud_artifact_id"] == plate

    def scene(**params) -> dict:
        response = engine.http.get(f"{base}/scene.glb", params={"points": 200_000, **params})
        assert response.status_code == 200, response.text
        return gltf_json(response.content)

    def rings(document: dict) -> set[int]:
        names = [n["name"] for n in document["nodes"]]
        return {int(n.removeprefix("defect-")) for n in names if n.startswith("defect-")}

    newest = scene()
    assert newest["asset"]["extras"]["scene_run"]["run_id"] == second["id"]
    assert newest["asset"]["extras"]["cloud"]["artifact_id"] == plate
    assert rings(newest) == set()  # the plate is flat: no finding, and none of the assembly's
    outlines = [n["name"] for n in newest["nodes"] if n["name"].startswith("panel-")]
    assert len(outlines) == 1
    assembly = scene(run=first["id"])
    assert rings(assembly) == {d["id"] for d in defects}
    assert len([n for n in assembly["nodes"] if n["name"].startswith("panel-")]) == 4
    assert engine.http.delete(f"{base}/artifacts/{plate}").status_code == 204
    assert scene()["asset"]["extras"]["scene_run"]["run_id"] == first["id"]
    gone = engine.http.get(f"{base}/scene.glb", params={"run": second["id"]})
    assert gone.status_code == 404 and "cloud it measured was deleted" in gone.json()["detail"]


def test_a_measurement_that_leaves_a_seam_unmeasured_says_so_everywhere(
    embedded_engine_factory, tmp_path
):
    """A seam no edge model explains is unmeasured: the job succeeds with a warning (its
    message, its record, its run), the job's log names the seam and why, the sync lists
    the warning with the count of seams, and the scene draws the seam apart with why."""
    from vista_client import Headset, VistaClient

    from tests.edgeclouds import seam_cloud
    from tests.test_run_pages import gltf_json

    engine = embedded_engine_factory()
    path = tmp_path / "rebate.ply"
    write_ply(path, seam_cloud(2.0, 0.0, ("rebate", 1.0), ("square", 0)))
    cloud = _upload(engine, path, "cloud", "application/x-ply")
    run = engine.run([{"name": "measure", "kind": "defects.measure", "inputs": [cloud]}])
    job = engine.wait(run["jobs"][0]["id"])
    assert job["status"] == "succeeded", job
    assert job["warning"].startswith("none of the 1 seam measured")
    assert (
        "not judged — seam 0 (P0–P1): only" in job["warning"] and "fits no model" in job["warning"]
    )
    assert job["message"].startswith("done, with a warning: none of the 1 seam measured")
    assert job["result"]["unmeasured_seams"] == 1
    runs = engine.http.get(f"/api/v1/inspections/{engine.inspection}/runs").json()["items"]
    assert runs[0]["warning"] == f"measure: {job['warning']}"
    view = engine.http.get(f"/api/v1/jobs/{job['id']}/view").json()
    assert any(
        line["message"].startswith("seam 0 (P0–P1) unmeasured: only") for line in view["log"]
    )
    synced = engine.http.get("/api/v1/sync", params={"inspection": engine.inspection}).json()
    assert synced["warnings"] == [
        {"job_id": job["id"], "run_id": run["id"], "kind": "defects.measure", "step": "measure",
         "warning": job["warning"], "unmeasured_seams": 1}
    ]  # fmt: skip
    headset = Headset(VistaClient(engine.server.url, engine.token), engine.inspection)
    headset.sync()
    assert [w["warning"] for w in headset.warnings] == [job["warning"]]
    scene = engine.http.get(f"/api/v1/inspections/{engine.inspection}/scene.glb")
    document = gltf_json(scene.content)
    groups = {n["name"]: n for n in document["nodes"] if "children" in n}
    assert "unmeasured-seams" in groups and "seams" not in groups
    seam = next(n for n in document["nodes"] if n["name"] == "seam-0")
    assert "fits no model" in seam["extras"]["unmeasured"]


def test_odometry_train_then_run_with_the_model_and_without(embedded_engine_factory, tmp_path):
    """A frame sequence uploaded as a tar.gz: `odometry.train` builds OE-Net from it, an
    `odometry` step after it runs that model, another runs vista's method; with the
    archive's truth both are evaluated. A sequence without truth cannot train, and oenet
    without a model is refused with what to add."""
    from tests.sequences import pack, small_sequence

    folder = small_sequence(tmp_path / "seq", seconds=0.3)
    engine = embedded_engine_factory()
    frames = _upload(engine, pack(folder, tmp_path / "seq.tar.gz"), "frames", "application/gzip")
    base = f"/api/v1/inspections/{engine.inspection}/artifacts"
    uploaded = engine.http.get(f"{base}/{frames}").json()
    assert uploaded["meta"]["frames"] == 19 and uploaded["meta"]["truth"]
    run = engine.run(
        [
            {
                "name": "train",
                "kind": "odometry.train",
                "inputs": [frames],
                "params": {"epochs": 1, "batch": 8, "device": "cpu"},
            },
            {
                "name": "oenet",
                "kind": "odometry.run",
                "inputs": [frames],
                "after": ["train"],
                "params": {"method": "oenet"},
            },
            {"name": "vista", "kind": "odometry.run", "inputs": [frames]},
        ]
    )
    train, oenet, vista = [engine.wait(j["id"], timeout=240) for j in run["jobs"]]
    assert [j["status"] for j in (train, oenet, vista)] == ["succeeded"] * 3, (train, oenet, vista)
    assert train["result"]["architecture"] == "oenet"
    assert train["result"]["split"] == {"train": 14, "val": 2, "test": 2}
    scores = vista["result"]["evaluation"]
    assert scores["poses"] == 19 and vista["result"]["flagged"] == 0
    assert scores["rmse_dx_mm"] < 0.05 and scores["rmse_dy_mm"] < 0.05
    assert scores["rmse_dtheta_deg"] < 0.05
    assert oenet["result"]["evaluation"]["poses"] == 19  # its accuracy is the bench's business
    listed = engine.http.get(base, params={"limit": 100}).json()["items"]
    made = {(a["job_id"], a["name"], a["kind"]) for a in listed}
    assert {(train["id"], "oenet.onnx", "model"), (train["id"], "training.json", "report")} <= made
    for job in (oenet, vista):
        assert {
            (job["id"], "trajectory.tum", "trajectory"),
            (job["id"], "odometry.json", "report"),
            (job["id"], "trajectory.png", "plot"),
            (job["id"], "evaluation.json", "report"),
        } <= made
    view = engine.http.get(f"/api/v1/jobs/{vista['id']}/view").json()  # its run page
    path, error, figures = view["panels"]
    assert [p["type"] for p in view["panels"]] == ["plot", "plot", "figures"]
    estimate, truth = path["lines"][:2]
    assert path["equal_axes"] and len(estimate["x"]) == len(estimate["band"]) == 19
    assert truth["name"] == "truth" and abs(truth["x"][-1] - estimate["x"][-1]) < 0.01
    assert error["lines"][0]["y"][0] == 0 and max(error["lines"][0]["y"]) < 1  # mm
    shown = {f["label"]: f for f in figures["figures"]}
    assert shown["frames"]["value"] == 19 and shown["drift"]["value"] is not None
    assert {a["name"] for a in view["outputs"]} >= {"trajectory.tum", "evaluation.json"}
    assert [a["id"] for a in view["inputs"]] == [frames]
    messages = [line["message"] for line in view["log"]]  # its progress, oldest first
    assert messages[0] == "unpacking seq.tar.gz" and messages[-1].startswith("18 pairs")
    assert all(line["attempt"] == 1 for line in view["log"])
    train_page = engine.http.get(f"/api/v1/jobs/{train['id']}/view").json()
    assert any(line["message"].startswith("exported oenet.onnx") for line in train_page["log"])
    assert not any(
        "/tmp" in line["message"] or "scratch" in line["message"] for line in train_page["log"]
    )
    trained = engine.http.get(f"/api/v1/jobs/{train['id']}/view").json()["panels"]
    assert trained[0]["title"] == "Training" and trained[0]["lines"][0]["x"] == [1.0]
    assert {"label": "architecture", "value": "oenet", "unit": "", "note": ""} in trained[1][
        "figures"
    ]
    tum = next(a for a in listed if a["job_id"] == vista["id"] and a["kind"] == "trajectory")
    assert tum["media_type"] == "text/plain"
    assert len(engine.http.get(f"{base}/{tum['id']}/content").text.splitlines()) == 19

    bare = _upload(
        engine, pack(folder, tmp_path / "bare.zip", truth=False), "frames", "application/zip"
    )
    refused = engine.run([{"name": "train", "kind": "odometry.train", "inputs": [bare]}])
    train = engine.wait(refused["jobs"][0]["id"], timeout=60)
    assert train["status"] == "failed" and "has no truth.tum" in train["error"]
    oenet = engine.http.post(  # OE-Net without its model: refused when the run is made
        f"/api/v1/inspections/{engine.inspection}/runs",
        json={
            "steps": [
                {
                    "name": "o",
                    "kind": "odometry.run",
                    "inputs": [bare],
                    "params": {"method": "oenet"},
                }
            ]
        },
    )
    assert oenet.status_code == 422 and "with method oenet" in oenet.json()["detail"]
    (folder / "frames" / "000002.png").write_bytes(b"\x89PNG\r\n\x1a\n but no image")
    broken = engine.http.post(  # refused at the door, naming the frame: no job fails later
        f"/api/v1/inspections/{engine.inspection}/artifacts",
        params={"kind": "frames", "name": "broken.zip"},
        content=pack(folder, tmp_path / "broken.zip").read_bytes(),
        headers={"content-type": "application/zip"},
    )
    assert broken.status_code == 422
    assert "seq/frames/000002.png is neither a PNG nor a JPEG" in broken.json()["detail"]


def test_depth_teacher_then_student_then_predict(embedded_engine_factory, tmp_path):
    """A simulated drive uploaded as a tar.gz: `depth.train` builds a teacher from it, a
    second `depth.train` distils a student from that teacher, `depth.predict` runs the
    student on the drive and on a single image: depth PNGs at the images' size, previews,
    camera-frame clouds and a report. A student without a teacher, and a drive without
    calibration, are refused with what is missing."""
    from services.lib.kitti import read_depth_png
    from tests.depthfiles import pack_drive, small_drive

    folder = small_drive(tmp_path / "drive")
    engine = embedded_engine_factory()
    drive = _upload(
        engine, pack_drive(folder, tmp_path / "drive.tar.gz"), "drive", "application/gzip"
    )
    image = _upload(engine, folder / "image_02" / "0000000001.png", "image", "image/png")
    base = f"/api/v1/inspections/{engine.inspection}/artifacts"
    # a camera calibration for the single image, in KITTI's own text format
    (tmp_path / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\nP_rect_02: 360.0 0 64.0 0 0 360.0 32.0 0 0 0 1 0\n"
    )
    calibration = _upload(engine, tmp_path / "calib_cam_to_cam.txt", "calibration", "text/plain")
    assert engine.http.get(f"{base}/{calibration}").json()["meta"]["focal_px"] == 360.0
    (tmp_path / "bad.txt").write_text("P_rect_02: 1 2 3\n")
    refused = engine.http.post(
        base,
        params={"kind": "calibration", "name": "bad.txt"},
        content=(tmp_path / "bad.txt").read_bytes(),
        headers={"content-type": "text/plain"},
    )
    assert refused.status_code == 422 and "no P_rect_02 (3 × 4)" in refused.json()["detail"]
    uploaded = engine.http.get(f"{base}/{drive}").json()
    assert uploaded["meta"] == {
        "frames": 3,
        "stereo": True,
        "depth": True,
        "scans": False,
        "poses": True,
    }
    small = {"width": 128, "height": 64, "epochs": 1, "batch": 2, "device": "cpu"}
    run = engine.run(
        [
            {
                "name": "teacher",
                "kind": "depth.train",
                "inputs": [drive],
                "params": {**small, "network": "teacher", "supervision": "stereo"},
            },
            {
                "name": "student",
                "kind": "depth.train",
                "inputs": [drive],
                "after": ["teacher"],
                "params": {**small, "network": "student"},
            },
            {
                "name": "predict",
                "kind": "depth.predict",
                "inputs": [drive, image],
                "after": ["student"],
            },
            {
                "name": "adapt",
                "kind": "depth.train",
                "inputs": [drive],
                "after": ["teacher"],
                "params": {**small, "network": "teacher", "supervision": "depth"},
            },
            {"name": "shipped", "kind": "depth.predict", "inputs": [image, calibration]},
        ]
    )
    teacher, student, predict, adapt, shipped = [
        engine.wait(j["id"], timeout=300) for j in run["jobs"]
    ]
    assert [j["status"] for j in (teacher, student, predict, adapt, shipped)] == [
        "succeeded"
    ] * 5, (teacher, student, predict, adapt, shipped)
    assert teacher["result"]["architecture"] == "monodepth2-resnet18"
    assert student["result"]["architecture"] == "deeplabv3plus-mobilenetv2"
    assert predict["result"]["images"] == 4
    listed = engine.http.get(base, params={"limit": 200}).json()["items"]
    made = {(a["job_id"], a["name"], a["kind"]) for a in listed}
    assert {
        (teacher["id"], "depth.onnx", "model"),
        (student["id"], "training.json", "report"),
    } <= made
    assert {
        (predict["id"], "drive-0000000002.depth.png", "depth"),
        (predict["id"], "drive-0000000002.color.png", "plot"),
        (predict["id"], "drive-0000000002.ply", "cloud"),
        (predict["id"], "0000000001.depth.png", "depth"),
        (predict["id"], "depth.json", "report"),
    } <= made
    depth_map = next(
        a for a in listed if a["name"] == "0000000001.depth.png" and a["job_id"] == predict["id"]
    )
    saved = tmp_path / "got.png"
    saved.write_bytes(engine.http.get(f"{base}/{depth_map['id']}/content").content)
    depth = read_depth_png(saved)
    assert depth.shape == (64, 128) and (depth > 0).all()

    alone = engine.http.post(  # a student without its teacher: refused when the run is made
        f"/api/v1/inspections/{engine.inspection}/runs",
        json={
            "steps": [
                {
                    "name": "student",
                    "kind": "depth.train",
                    "inputs": [drive],
                    "params": {**small, "network": "student"},
                }
            ]
        },
    )
    assert alone.status_code == 422 and "with network student" in alone.json()["detail"]
    (folder / "calib.json").unlink()
    response = engine.http.post(
        base,
        params={"kind": "drive", "name": "nocalib.tar.gz"},
        content=pack_drive(folder, tmp_path / "nocalib.tar.gz").read_bytes(),
        headers={"content-type": "application/gzip"},
    )
    assert response.status_code == 422 and "no calib.json" in response.json()["detail"]


def test_track_job_follows_a_car_and_refuses_missing_models(embedded_engine_factory, tmp_path):
    """A packed drive uploaded as `lidar`: `track` follows track 0 with resets by the
    shipped detector and writes TRACK.json, its plot and the evaluation; a run without the
    target, and a Siamese tracker without its encoder, are refused."""
    from tests.lidarfiles import pack_sequence, small_drive

    drive = small_drive(tmp_path / "drive")
    engine = embedded_engine_factory()
    sequence = _upload(
        engine, pack_sequence(drive, tmp_path / "drive.tar.gz"), "lidar", "application/gzip"
    )
    base = f"/api/v1/inspections/{engine.inspection}/artifacts"
    assert engine.http.get(f"{base}/{sequence}").json()["meta"]["frames"] == 12
    run = engine.run(
        [
            {
                "name": "track",
                "kind": "tracking.track",
                "inputs": [sequence],
                "params": {"track_id": 0, "reset": "adaptive:20"},
            }
        ]
    )
    job = engine.wait(run["jobs"][0]["id"], timeout=120)
    assert job["status"] == "succeeded", job
    assert job["result"]["frames"] == 12 and job["result"]["success"] > 50
    made = {
        (a["name"], a["kind"])
        for a in engine.http.get(base, params={"limit": 200}).json()["items"]
        if a["job_id"] == job["id"]
    }
    assert made == {("track.json", "report"), ("track.png", "plot"), ("evaluation.json", "report")}
    refused = engine.run(
        [
            {
                "name": "t",
                "kind": "tracking.track",
                "inputs": [sequence],
                "params": {"track_id": 0, "tracker": "siamese"},
            }
        ]
    )
    failed = engine.wait(refused["jobs"][0]["id"], timeout=60)
    assert failed["status"] == "failed" and "encoder is needed" in failed["error"]
    response = engine.http.post(
        f"/api/v1/inspections/{engine.inspection}/runs",
        json={
            "steps": [
                {
                    "name": "t",
                    "kind": "tracking.track",
                    "inputs": [sequence],
                    "params": {"reset": "never"},
                }
            ]
        },
    )
    assert response.status_code == 422 and "either by track_id" in response.text
    for params, phrase in (
        ({"network": "siamese", "fine_tune": True}, "fine_tune applies to the detector"),
        ({"network": "detector"}, "only used with fine_tune"),
    ):
        model = [] if "siamese" in params.values() else [_shipped_detector(engine)]
        refused = engine.run(
            [
                {
                    "name": "t",
                    "kind": "tracking.train",
                    "inputs": [sequence, *model],
                    "params": params,
                }
            ]
        )
        failed = engine.wait(refused["jobs"][0]["id"], timeout=60)
        assert failed["status"] == "failed" and phrase in failed["error"].lower(), failed


def test_detect_job_judges_each_box_and_draws_them_on_the_images(embedded_engine_factory, tmp_path):
    """`tracking.detect` on a labelled simulated drive: every scan's boxes with their scores
    and verdicts against the labels, the recall and precision, and a camera image named as
    its scan drawn with its boxes; images not named as a scan, or of no scan in the
    sequence, and a model for the geometric detector are refused, naming the file."""
    import cv2

    from tests.lidarfiles import pack_sequence, small_drive

    drive = small_drive(tmp_path / "drive")
    engine = embedded_engine_factory()
    sequence = _upload(
        engine, pack_sequence(drive, tmp_path / "drive.tar.gz"), "lidar", "application/gzip"
    )
    images = tmp_path / "images"
    images.mkdir()
    for name in ("000003.png", "camera.png", "000099.png"):
        cv2.imwrite(str(images / name), np.full((375, 1242, 3), 90, np.uint8))
    image = _upload(engine, images / "000003.png", "image", "image/png")
    run = engine.run([{"name": "d", "kind": "tracking.detect", "inputs": [sequence, image]}])
    job = engine.wait(run["jobs"][0]["id"], timeout=120)
    assert job["status"] == "succeeded", job
    assert job["result"]["scans"] == 12 and job["result"]["detections"] > 0
    base = f"/api/v1/inspections/{engine.inspection}/artifacts"
    made = {
        a["name"]: a["id"]
        for a in engine.http.get(base, params={"limit": 200}).json()["items"]
        if a["job_id"] == job["id"]
    }
    assert set(made) == {"detections.json", "000003.detections.png"}
    document = engine.http.get(f"{base}/{made['detections.json']}/content").json()
    scan = document["scans"][3]
    assert scan["frame"] == 3 and scan["scored"]
    assert len(scan["boxes"]) == len(scan["scores"]) == len(scan["true_positive"])
    assert document["evaluation"]["scans"] == 12
    # judged against each scan's own labels: the labelled cars within 40 m, frame by frame
    from services.lib import kitti
    from services.tracking.sequence import open_sequence

    labelled = open_sequence(drive)
    cars = labelled.labels.of_type("Car")
    where = kitti.camera_to_lidar(cars.camera_box, labelled.calibration)
    near = np.hypot(where[:, 0], where[:, 1]) <= 40
    assert [s["cars_near"] for s in document["scans"]] == [
        int((near & (cars.frame == frame)).sum()) for frame in range(12)
    ]
    assert job["result"]["recall_near"] >= 0.8  # the lead car and the cars near it, every scan
    drawn = engine.http.get(f"{base}/{made['000003.detections.png']}/content").content
    picture = cv2.imdecode(np.frombuffer(drawn, np.uint8), cv2.IMREAD_COLOR)
    assert picture.shape == (375, 1242, 3) and (picture != 90).any()  # the boxes drawn on it
    for name, phrase in (
        ("camera.png", "is not named as a scan"),
        ("000099.png", "the sequence has no scan 99"),
    ):
        other = _upload(engine, images / name, "image", "image/png")
        refused = engine.run(
            [{"name": "d", "kind": "tracking.detect", "inputs": [sequence, other]}]
        )
        failed = engine.wait(refused["jobs"][0]["id"], timeout=60)
        assert (
            failed["status"] == "failed" and phrase in failed["error"] and name in failed["error"]
        )
    refused = engine.run(
        [
            {
                "name": "d",
                "kind": "tracking.detect",
                "inputs": [sequence, _shipped_detector(engine)],
                "params": {"detector": "geometric"},
            }
        ]
    )
    failed = engine.wait(refused["jobs"][0]["id"], timeout=60)
    assert failed["status"] == "failed" and "leave it out" in failed["error"]


def _shipped_detector(engine: Engine) -> int:
    from services.tracking.detect_learned import DEFAULT_MODEL

    return _upload(engine, DEFAULT_MODEL, "model", "application/octet-stream")


def test_a_job_error_is_one_sentence_without_server_paths():
    assert sentence("reading /srv/vista/data/files/7/ab.ply: bad\n  header") == (
        "Reading ab.ply: bad header."
    )
    assert sentence("see https://example.org/a/b, 3/4 mm") == "See https://example.org/a/b, 3/4 mm."
    assert len(sentence("x" * 2000)) == 500
