"""A run is checked when it is created: each step's inputs against what its job kind
reads; an artifact's kind from the known list, its content checked whatever media type
was declared."""

from __future__ import annotations

import pytest
from sqlalchemy import func, select

from supervisor.engine.registry import artifact_kinds, load_kinds
from supervisor.models import Artifact, Job, Run
from tests.conftest import auth
from tests.plyfiles import ply_bytes
from tests.test_upload_limits import onnx_model_bytes

JSON = {"content-type": "application/json"}
PLY = {"content-type": "application/x-ply"}


@pytest.fixture
def upload(client, tokens):
    token = tokens["inspector"]
    inspection = client.post(
        "/api/v1/inspections", json={"title": "t", "area": "cabin"}, headers=auth(token)
    ).json()["id"]

    def send(data: bytes, *, kind: str, name: str, headers: dict):
        return client.post(
            f"/api/v1/inspections/{inspection}/artifacts",
            params={"kind": kind, "name": name},
            content=data,
            headers={**auth(token), **headers},
        )

    def ids(data: bytes, kind: str, name: str, headers: dict) -> int:
        response = send(data, kind=kind, name=name, headers=headers)
        assert response.status_code == 201, response.text
        return response.json()["id"]

    def run(steps: list[dict]):
        return client.post(
            f"/api/v1/inspections/{inspection}/runs", json={"steps": steps}, headers=auth(token)
        )

    send.ids, send.run = ids, run
    return send


def _frames_zip(tmp_path) -> bytes:
    from tests.sequences import archive_bytes, sequence_members, small_sequence

    return archive_bytes(sequence_members(small_sequence(tmp_path / "seq", seconds=0.05)), "zip")


def _counts(runtime) -> tuple[int, int]:
    with runtime.db.read() as session:
        return tuple(session.scalar(select(func.count()).select_from(t)) for t in (Run, Job))


def test_steps_fed_the_wrong_inputs_are_refused_naming_the_step(upload, runtime, tmp_path):
    report = upload.ids(b'{"points": 3}', "report", "r.json", JSON)
    scan = upload.ids(ply_bytes(tmp_path), "scan", "scan_000.ply", PLY)
    cloud = upload.ids(ply_bytes(tmp_path), "cloud", "c.ply", PLY)
    other_cloud = upload.ids(ply_bytes(tmp_path), "cloud", "d.ply", PLY)
    pairs = upload.ids(b'{"pairs": []}', "pairs", "pairs.json", JSON)
    manifest = upload.ids(b'{"scans": []}', "scans", "scans.json", JSON)
    frames = upload.ids(
        _frames_zip(tmp_path), "frames", "seq.zip", {"content-type": "application/zip"}
    )
    model = upload.ids(
        onnx_model_bytes(), "model", "m.onnx", {"content-type": "application/octet-stream"}
    )
    cases = [
        (
            [{"name": "look", "kind": "scan.inspect", "inputs": [report]}],
            f"steps[0] (look).inputs: artifact {report} is a 'report', which scan.inspect",
        ),
        (
            [{"name": "m", "kind": "defects.measure", "inputs": [scan]}],
            f"artifact {scan} is a 'scan', which defects.measure does not read; it reads exactly 1 'cloud'",
        ),
        (
            [{"name": "cal", "kind": "stitching.calibrate", "inputs": [scan]}],
            f"artifact {scan} is a 'scan', which stitching.calibrate does not read",
        ),
        (
            [{"name": "s", "kind": "stitching.stitch"}],
            "steps[0] (s): stitching.stitch needs exactly 1 'scans' artifact",
        ),
        (
            [{"name": "s", "kind": "stitching.stitch", "inputs": [manifest, scan]}],
            "stitching.stitch needs exactly 1 'handeye' artifact (the hand-eye calibration (uploaded or "
            "from stitching.calibrate)) and gets none: upload it as kind 'handeye' and list its id in "
            "inputs or list a step of kind 'stitching.calibrate' in after.",
        ),
        (
            [{"name": "m", "kind": "defects.measure", "inputs": [cloud, other_cloud]}],
            f"defects.measure reads exactly 1 'cloud' (the stitched point cloud); it would get 2: "
            f"artifact {cloud}, artifact {other_cloud}",
        ),
        (
            [
                {"name": "cal", "kind": "stitching.calibrate", "inputs": [pairs]},
                {
                    "name": "s",
                    "kind": "stitching.stitch",
                    "inputs": [manifest, scan],
                    "after": ["cal"],
                },
                {"name": "m", "kind": "defects.measure", "inputs": [cloud], "after": ["s"]},
            ],
            "steps[2] (m): defects.measure reads exactly 1 'cloud' (the stitched point cloud); it "
            f"would get 2: artifact {cloud}, stitched.ply of step 's'.",
        ),
        (
            [{"name": "m", "kind": "defects.measure"}],
            "defects.measure needs exactly 1 'cloud' artifact (the stitched point cloud) and gets "
            "none: upload it as kind 'cloud' and list its id in inputs or list a step of kind "
            "'stitching.stitch' in after.",  # not depth.predict: its cloud is no panel's
        ),
        (
            [
                {
                    "name": "o",
                    "kind": "odometry.run",
                    "inputs": [frames],
                    "params": {"method": "oenet"},
                }
            ],
            "steps[0] (o): with method oenet, odometry.run needs one 'model' artifact (an "
            "OE-Net model (method oenet only)) and gets none: upload it as kind 'model' and list "
            "its id in inputs or list a step of kind 'odometry.train' in after.",
        ),
        (
            [{"name": "o", "kind": "odometry.run", "inputs": [frames, model]}],
            "steps[0] (o): with method vista, odometry.run reads no 'model' (an OE-Net model "
            "(method oenet only)): leave it out, or set method to oenet.",
        ),
    ]
    for steps, phrase in cases:
        refused = upload.run(steps)
        assert refused.status_code == 422, (steps, refused.text)
        assert phrase in refused.json()["detail"], refused.json()["detail"]
    assert _counts(runtime) == (0, 0)

    # The same steps fed rightly are accepted: the outputs of `after` steps count.
    chain = [
        {"name": "cal", "kind": "stitching.calibrate", "inputs": [pairs]},
        {"name": "s", "kind": "stitching.stitch", "inputs": [manifest, scan], "after": ["cal"]},
        {"name": "m", "kind": "defects.measure", "after": ["s"]},
        {"name": "look", "kind": "scan.inspect", "inputs": [scan, cloud]},
        {"name": "again", "kind": "scan.inspect", "after": ["s"]},
    ]
    accepted = upload.run(chain)
    assert accepted.status_code == 201, accepted.text
    assert _counts(runtime) == (1, len(chain))
    # An older name is an alias: the step runs the kind and is stored under its name.
    older = upload.run([{"name": "m", "kind": "measure", "inputs": [cloud]}])
    assert older.status_code == 201, older.text
    assert [job["kind"] for job in older.json()["jobs"]] == ["defects.measure"]


def test_every_kinds_outputs_are_known_artifact_kinds(settings):
    kinds = load_kinds(settings.extra_job_kinds)
    for kind in kinds.values():
        if kind.name.startswith("test."):
            continue
        service, _, verb = kind.name.partition(".")
        assert service.isidentifier() and verb, f"{kind.name} is not <service>.<verb>"
        assert {o.kind for o in kind.outputs} <= set(artifact_kinds()), kind.name
        assert {k for spec in kind.inputs for k in spec.kinds} <= set(artifact_kinds()), kind.name


def test_artifact_kinds_and_content_are_checked_whatever_the_media_type(upload, runtime, tmp_path):
    banana = upload(ply_bytes(tmp_path), kind="banana", name="b.ply", headers=PLY)
    assert banana.status_code == 422 and "kind" in banana.json()["detail"]
    assert "'cloud'" in banana.json()["detail"]  # the message lists the known kinds
    for media_type in ("text/plain", "application/octet-stream"):
        noise = upload(
            b"\x13\x37" * 500, kind="cloud", name="c.ply", headers={"content-type": media_type}
        )
        assert noise.status_code == 422, noise.text
        assert "must be a PLY point cloud" in noise.json()["detail"]
        truncated = upload(
            ply_bytes(tmp_path)[:-100],
            kind="other",
            name="c.ply",
            headers={"content-type": media_type},
        )
        assert truncated.status_code == 422 and "not a valid PLY" in truncated.json()["detail"]
        kept = upload(
            ply_bytes(tmp_path), kind="scan", name="s.ply", headers={"content-type": media_type}
        )
        assert kept.status_code == 201, kept.text
        body = kept.json()
        assert body["media_type"] == "application/x-ply" and body["meta"]["ply"]["vertex_count"]
    wrong_json = upload(
        b"not json", kind="pairs", name="p.txt", headers={"content-type": "text/plain"}
    )
    assert wrong_json.status_code == 422 and "kind=pairs" in wrong_json.json()["detail"]
    note = upload(b"free text", kind="other", name="n.txt", headers={"content-type": "text/plain"})
    assert note.status_code == 201 and note.json()["media_type"] == "text/plain"
    with runtime.db.read() as session:
        assert session.scalar(select(func.count()).select_from(Artifact)) == 3
