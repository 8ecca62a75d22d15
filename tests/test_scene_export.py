"""scene.glb: the Khronos validator finds no error, and re-imported with an independent
reader (pygltflib) every marker sits on its defect to 0.1 mm and every anchor on its pose."""

from __future__ import annotations

import json
import re
import struct
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from pygltflib import GLTF2
from scipy.spatial.transform import Rotation

from services.lib.pointcloud.ply import PointCloud, write_ply
from supervisor.exports.gltf import pose_to_gltf, quaternion_xyzw, rotation_from_y
from supervisor.exports.scene import TYPE_COLORS, rgba
from tests.conftest import auth
from tests.seeding import seed_defects

WEB = Path(__file__).resolve().parent.parent / "clients" / "web"
VALIDATOR = WEB / "tools" / "validate-gltf.mjs"
MARKERS = [
    {
        "name": "cabin-left",
        "area": "cabin",
        "base_T_marker": [[0, -1, 0, 1200.5], [1, 0, 0, -340.25], [0, 0, 1, 95.0], [0, 0, 0, 1]],
        "size_mm": 210.0,
        "image": "vista-cabin",
    },
    {
        "name": "cargo",
        "area": "cargo",
        "base_T_marker": [[1, 0, 0, -50.0], [0, 0, -1, 800.0], [0, 1, 0, 0.0], [0, 0, 0, 1]],
        "size_mm": 150.0,
    },
]


PANELS = [
    {
        "id": i,
        "centroid": [75.0 + 150 * i, 100.0, 102.5],
        "normal": [0.0, 0.0, 1.0],
        "area_mm2": 29_000.0,
        "outline": [
            [5.0 + 150 * i, 5.0, 102.5],
            [145.0 + 150 * i, 5.0, 102.5],
            [145.0 + 150 * i, 195.0, 102.5],
            [5.0 + 150 * i, 195.0, 102.5],
        ],
    }
    for i in range(2)
]
SEAM = {
    "id": 0,
    "panels": [0, 1],
    "start": [150.0, 5.0, 102.5],
    "end": [150.0, 195.0, 102.5],
    "length_mm": 190.0,
    "sections": [{"at": [150.0, y, 102.5]} for y in (20.0, 60.0, 100.0, 140.0, 180.0)],
}


def validate(path: Path) -> dict:
    """The glTF-Validator's report of one file (npm package gltf-validator)."""
    if not (WEB / "node_modules" / "gltf-validator").exists():
        pytest.fail("clients/web/node_modules is missing: run `make install-test`")
    done = subprocess.run(
        ["node", str(VALIDATOR), str(path)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode in (0, 1), done.stderr
    return json.loads(done.stdout)[0]


def _upload_ply(client, token, inspection, path: Path, kind: str) -> int:
    answer = client.post(
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": kind, "name": path.name},
        content=path.read_bytes(),
        headers={**auth(token), "Content-Type": "application/x-ply"},
    )
    assert answer.status_code == 201, answer.text
    return answer.json()["id"]


@pytest.fixture
def scene_inspection(client, tokens, runtime, tmp_path) -> dict:
    token = tokens["inspector"]
    inspection = client.post(
        "/api/v1/inspections",
        json={"title": "sidewall", "area": "cabin", "markers": MARKERS},
        headers=auth(token),
    ).json()["id"]
    rng = np.random.default_rng(3)
    points = (rng.random((30_000, 3)) * [300, 200, 5] + [0, 0, 100]).astype(np.float32)
    colors = rng.integers(0, 256, (30_000, 3), dtype=np.uint8)
    write_ply(tmp_path / "cloud.ply", PointCloud(points=points, colors=colors))
    _upload_ply(client, token, inspection, tmp_path / "cloud.ply", "cloud")
    grid = np.stack(np.meshgrid(np.arange(4.0), np.arange(3.0)), -1).reshape(-1, 2) * 50
    vertices = np.column_stack([grid, np.full(len(grid), 100.0)]).astype(np.float32)
    quads = [
        (r * 4 + c, r * 4 + c + 1, r * 4 + c + 4, r * 4 + c + 5) for r in range(2) for c in range(3)
    ]
    faces = np.array([f for a, b, c, d in quads for f in ((a, b, d), (a, d, c))])
    write_ply(tmp_path / "panels.ply", PointCloud(points=vertices), faces=faces)
    _upload_ply(client, token, inspection, tmp_path / "panels.ply", "mesh")
    answer = client.post(  # a measurement's RESULT.json: its panels are outlined
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": "report", "name": "defects.json"},
        content=json.dumps({"panels": PANELS, "seams": [SEAM]}).encode(),
        headers={**auth(token), "Content-Type": "application/json"},
    )
    assert answer.status_code == 201, answer.text
    ids = seed_defects(runtime, inspection, 40)
    client.put(
        f"/api/v1/defects/{ids[5]}/judgments/me",
        json={"verdict": "confirmed"},
        headers=auth(token),
    )
    return {"id": inspection, "defects": ids, "points": points}


def test_scene_is_valid_gltf_with_markers_on_the_defects(
    client, tokens, scene_inspection, tmp_path
):
    inspection = scene_inspection["id"]
    answer = client.get(
        f"/api/v1/inspections/{inspection}/scene.glb",
        params={"points": 10_000},
        headers=auth(tokens["device"]),
    )
    assert answer.status_code == 200 and answer.headers["content-type"] == "model/gltf-binary"
    path = tmp_path / "scene.glb"
    path.write_bytes(answer.content)

    report = validate(path)
    assert report["issues"]["numErrors"] == 0, report["issues"]["messages"]
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"]

    gltf = GLTF2().load_binary(str(path))
    nodes = {n.name: n for n in gltf.nodes}
    assert gltf.asset.extras["units"] == "metre" and gltf.asset.extras["up"] == "+Y"
    defects = client.get(
        "/api/v1/defects", params={"inspection": inspection}, headers=auth(tokens["viewer"])
    ).json()["items"]
    assert len(defects) == 40
    for defect in defects:
        node = nodes[f"defect-{defect['id']}"]
        x, y, z = node.translation
        back_mm = np.array([x, -z, y]) * 1000.0  # glTF (m, +Y up) → base (mm, +Z up)
        assert np.abs(back_mm - defect["location_mm"]).max() < 0.1
        assert node.extras["defect_id"] == defect["id"] and node.extras["type"] == defect["type"]
        assert "status" not in node.extras and "consensus" not in node.extras  # the sync's
        assert node.scale[0] == pytest.approx(6.0 / 2000)  # extent 3 mm < the 6 mm minimum
        # a ring facing along the defect's normal: it circles the defect, it does not hide it
        x, y, z, w = node.rotation
        ring_axis = Rotation.from_quat([x, y, z, w]).apply([0.0, 1.0, 0.0])
        nx, ny, nz = defect["normal"]
        assert np.allclose(ring_axis, np.array([nx, nz, -ny]) / np.linalg.norm(defect["normal"]))
        ring = gltf.meshes[node.mesh].primitives[0]
        assert ring.mode == 4 and gltf.accessors[ring.attributes.POSITION].count == 96

    for marker in MARKERS:
        node = nodes[f"marker-{marker['name']}"]
        pose = np.array(marker["base_T_marker"], dtype=float)
        back = np.array([node.translation[0], -node.translation[2], node.translation[1]]) * 1000
        assert np.abs(back - pose[:3, 3]).max() < 1e-6
        assert node.extras["area"] == marker["area"] and node.extras["size_mm"] == marker["size_mm"]
        assert np.allclose(node.rotation, pose_to_gltf(pose)[1])

    cloud = gltf.meshes[nodes["cloud"].mesh].primitives[0]
    assert cloud.mode == 0 and cloud.attributes.COLOR_0 is not None
    assert gltf.accessors[cloud.attributes.POSITION].count == 10_000
    blob = gltf.binary_blob()
    view = gltf.bufferViews[gltf.accessors[cloud.attributes.POSITION].bufferView]
    xyz = np.frombuffer(blob, np.float32, 30_000, view.byteOffset).reshape(-1, 3)
    base = np.column_stack([xyz[:, 0], -xyz[:, 2], xyz[:, 1]]) * 1000
    source = scene_inspection["points"]
    assert (base.min(0) >= source.min(0) - 1e-3).all() and (
        base.max(0) <= source.max(0) + 1e-3
    ).all()
    panels = next(m for m in gltf.meshes if m.name.startswith("panels-"))
    assert gltf.accessors[panels.primitives[0].indices].count == 12 * 3
    # the measured panels: a closed line around each, labelled with the id seams refer to
    for panel in PANELS:
        node = nodes[f"panel-{panel['id']}"]
        assert (
            node.extras["panel"] == panel["id"] and node.extras["centroid_mm"] == panel["centroid"]
        )
        loop = gltf.meshes[node.mesh].primitives[0]
        assert loop.mode == 2  # LINE_LOOP
        accessor = gltf.accessors[loop.attributes.POSITION]
        view = gltf.bufferViews[accessor.bufferView]
        xyz = np.frombuffer(blob, np.float32, 3 * accessor.count, view.byteOffset).reshape(-1, 3)
        back = np.column_stack([xyz[:, 0], -xyz[:, 2], xyz[:, 1]]) * 1000
        assert np.abs(back - panel["outline"]).max() < 1e-3

    # the measured seams: a line through the sections from start to end
    seam = nodes["seam-0"]
    assert seam.extras["panels"] == [0, 1] and seam.extras["length_mm"] == 190.0
    strip = gltf.meshes[seam.mesh].primitives[0]
    assert strip.mode == 3 and gltf.accessors[strip.attributes.POSITION].count == 7  # LINE_STRIP


def test_scene_etag_conditional_get_and_changes(client, tokens, scene_inspection):
    """The ETag follows the geometry only: a judgment, a status, new tolerances leave it
    (they travel in the sync's defect data); a finding added, markers moved change it."""
    url = f"/api/v1/inspections/{scene_inspection['id']}/scene.glb"
    viewer, inspector = auth(tokens["viewer"]), auth(tokens["inspector"])
    first = client.get(url, headers=viewer)
    etag = first.headers["etag"]
    again = client.get(url, headers={**viewer, "If-None-Match": etag})
    assert again.status_code == 304 and again.content == b"" and again.headers["etag"] == etag
    target = scene_inspection["defects"][0]
    client.put(
        f"/api/v1/defects/{target}/judgments/me", json={"verdict": "rejected"}, headers=inspector
    )
    client.patch(
        f"/api/v1/defects/{target}",
        json={"status": "dismissed", "reason": "glare"},
        headers=inspector,
    )
    client.patch(
        f"/api/v1/inspections/{scene_inspection['id']}",
        json={"title": "renamed", "tolerances": {"step_mm": {"max": 0.9}}},
        headers=auth(tokens["admin"]),
    )
    judged = client.get(url, headers={**viewer, "If-None-Match": etag})
    assert judged.status_code == 304 and judged.headers["etag"] == etag
    client.post(
        "/api/v1/defects",
        json={"inspection_id": scene_inspection["id"], "type": "dent", "location_mm": [1, 2, 3]},
        headers=inspector,
    )
    changed = client.get(url, headers={**viewer, "If-None-Match": etag})
    assert changed.status_code == 200 and changed.headers["etag"] != etag
    moved = [dict(MARKERS[0], size_mm=MARKERS[0]["size_mm"] + 10)]
    client.patch(
        f"/api/v1/inspections/{scene_inspection['id']}", json={"markers": moved}, headers=inspector
    )
    remarked = client.get(url, headers={**viewer, "If-None-Match": changed.headers["etag"]})
    assert remarked.status_code == 200
    other_budget = client.get(url, params={"points": 2000}, headers=viewer)
    assert other_budget.headers["etag"] not in (etag, remarked.headers["etag"])
    sync = client.get(
        "/api/v1/sync", params={"inspection": scene_inspection["id"]}, headers=viewer
    ).json()
    assert sync["scene_etag"] == remarked.headers["etag"]


def test_scene_of_an_empty_inspection_and_bad_meshes(client, tokens, tmp_path):
    token = tokens["inspector"]
    inspection = client.post(
        "/api/v1/inspections", json={"title": "new", "area": "cargo"}, headers=auth(token)
    ).json()["id"]
    answer = client.get(f"/api/v1/inspections/{inspection}/scene.glb", headers=auth(token))
    path = tmp_path / "empty.glb"
    path.write_bytes(answer.content)
    assert validate(path)["issues"]["numErrors"] == 0
    assert client.get("/api/v1/inspections/999/scene.glb", headers=auth(token)).status_code == 404
    write_ply(tmp_path / "cloud.ply", PointCloud(points=np.zeros((10, 3), np.float32)))
    refused = client.post(
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": "mesh", "name": "cloud.ply"},
        content=(tmp_path / "cloud.ply").read_bytes(),
        headers={**auth(token), "Content-Type": "application/x-ply"},
    )
    assert refused.status_code == 422 and "no 'face' element" in refused.json()["detail"]
    bad_marker = dict(
        MARKERS[0], base_T_marker=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    )
    wrong = client.patch(
        f"/api/v1/inspections/{inspection}", json={"markers": [bad_marker]}, headers=auth(token)
    )
    assert wrong.status_code == 422 and "orthonormal" in wrong.text


def test_quaternions_match_rotations():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        q *= np.sign(np.linalg.det(q))
        x, y, z, w = quaternion_xyzw(q)
        rebuilt = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        assert np.abs(rebuilt - q).max() < 1e-9


def test_a_ring_turns_to_face_any_direction():
    rng = np.random.default_rng(1)
    for direction in [*rng.normal(size=(50, 3)), [0, -1, 0], [1, 0, 0], [0, 1e-12, 0]]:
        turned = Rotation.from_quat(rotation_from_y(direction)).apply([0.0, 1.0, 0.0])
        norm = np.linalg.norm(direction)
        expected = np.asarray(direction) / norm if norm > 1e-9 else [0.0, 1.0, 0.0]
        assert np.allclose(turned, expected, atol=1e-9), direction


def test_the_dashboard_colours_each_type_as_the_scene_does_and_distinctly():
    script = (WEB / "src" / "main.js").read_text()
    block = re.search(r"const TYPE_COLORS = \{(.*?)\};", script, re.S).group(1)
    assert dict(re.findall(r'(\w+): "(#[0-9a-f]{6})"', block)) == TYPE_COLORS
    rgb = np.array([rgba(c)[:3] for c in TYPE_COLORS.values()]) * 255
    closest = min(np.linalg.norm(a - b) for i, a in enumerate(rgb) for b in rgb[i + 1 :])
    assert closest > 80, "two types look alike"  # dent and bump were 58 apart


def test_readers_of_one_scene_at_different_budgets_all_get_it_whole(
    client, tokens, scene_inspection
):
    """Eight clients asking for the scene at alternating point budgets: each build kept
    one file and deleted the other budget's while it was about to be sent (500s: "File at
    path … does not exist"); each answer is now read through a handle taken before it."""
    url = f"/api/v1/inspections/{scene_inspection['id']}/scene.glb"
    viewer = auth(tokens["viewer"])

    def fetch(i: int) -> tuple[int, int, bytes]:
        answer = client.get(url, params={"points": (2000, 3000, 5000)[i % 3]}, headers=viewer)
        return answer.status_code, int(answer.headers.get("content-length", -1)), answer.content

    with ThreadPoolExecutor(8) as pool:
        answers = list(pool.map(fetch, range(48)))
    for status, length, body in answers:
        assert status == 200
        assert body[:4] == b"glTF" and length == len(body) == struct.unpack("<I", body[8:12])[0]
