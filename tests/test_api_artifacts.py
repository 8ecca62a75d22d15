from __future__ import annotations

import hashlib

import pytest
from sqlalchemy import func, select

from supervisor.models import Artifact
from tests.conftest import auth, make_settings
from tests.plyfiles import empty_cloud_bytes, plane_grid, ply_bytes, with_nan

PLY = {"content-type": "application/x-ply"}


@pytest.fixture
def inspection(client, tokens) -> int:
    response = client.post(
        "/api/v1/inspections",
        json={"title": "t", "area": "component"},
        headers=auth(tokens["inspector"]),
    )
    return response.json()["id"]


def _upload(client, token, inspection, data, *, name="scan.ply", kind="scan", headers=PLY):
    return client.post(
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": kind, "name": name},
        content=data,
        headers={**auth(token), **headers},
    )


def _stored_files(runtime) -> list:
    root = runtime.storage.root
    return [p for p in root.rglob("*") if p.is_file()]


def test_upload_validates_hashes_and_serves_ranges(client, tokens, inspection, tmp_path):
    data = ply_bytes(tmp_path, plane_grid(40, 50))
    created = _upload(client, tokens["inspector"], inspection, data)
    assert created.status_code == 201, created.text
    artifact = created.json()
    assert artifact["sha256"] == hashlib.sha256(data).hexdigest()
    assert artifact["size_bytes"] == len(data)
    assert artifact["meta"]["ply"]["vertex_count"] == 2000
    assert artifact["meta"]["ply"]["grid_shape"] == [40, 50]
    url = f"/api/v1/inspections/{inspection}/artifacts/{artifact['id']}/content"
    whole = client.get(url, headers=auth(tokens["viewer"]))
    assert whole.content == data and whole.headers["etag"] == f'"{artifact["sha256"]}"'
    part = client.get(url, headers={**auth(tokens["viewer"]), "Range": "bytes=10-109"})
    assert part.status_code == 206 and part.content == data[10:110]
    assert part.headers["content-range"] == f"bytes 10-109/{len(data)}"
    listed = client.get(
        f"/api/v1/inspections/{inspection}/artifacts", headers=auth(tokens["viewer"])
    )
    assert [a["id"] for a in listed.json()["items"]] == [artifact["id"]]


def test_delete_removes_row_and_file(client, tokens, inspection, tmp_path, runtime):
    artifact = _upload(client, tokens["inspector"], inspection, ply_bytes(tmp_path)).json()
    assert len(_stored_files(runtime)) == 1
    path = f"/api/v1/inspections/{inspection}/artifacts/{artifact['id']}"
    assert client.delete(path, headers=auth(tokens["viewer"])).status_code == 403
    assert client.delete(path, headers=auth(tokens["inspector"])).status_code == 204
    assert client.get(path, headers=auth(tokens["inspector"])).status_code == 404
    assert _stored_files(runtime) == []


@pytest.mark.parametrize(
    ("make", "status", "phrase"),
    [
        (lambda tmp: ply_bytes(tmp)[:-7], 422, "truncated"),
        (lambda tmp: bytes(range(256)) * 64, 422, "magic"),
        (lambda tmp: ply_bytes(tmp, with_nan(plane_grid(10, 10), 5)), 422, "vertex 5"),
        (lambda tmp: empty_cloud_bytes(), 422, "no points"),
        (lambda tmp: b"", 422, "empty"),
    ],
)
def test_bad_point_clouds_are_refused_and_nothing_is_stored(
    client, tokens, inspection, tmp_path, runtime, make, status, phrase
):
    response = _upload(client, tokens["inspector"], inspection, make(tmp_path))
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/problem+json"
    assert phrase in response.json()["detail"]
    with runtime.db.read() as session:
        assert session.scalar(select(func.count()).select_from(Artifact)) == 0
    assert _stored_files(runtime) == []


def test_wrong_content_type_is_415(client, tokens, inspection, tmp_path, runtime):
    for content_type in ("multipart/form-data; boundary=x", "text/html", None):
        headers = {"content-type": content_type} if content_type else {}
        response = _upload(
            client, tokens["inspector"], inspection, ply_bytes(tmp_path), headers=headers
        )
        assert response.status_code == 415, content_type
        assert "application/x-ply" in response.json()["detail"]
    assert _stored_files(runtime) == []


@pytest.mark.parametrize(
    ("media_type", "data", "phrase"),
    [
        ("application/json", b'{"pairs": [', "not valid JSON"),
        ("image/png", b"GIF89a", "PNG signature"),
        ("model/gltf-binary", b"PK\x03\x04", "GLB magic"),
    ],
)
def test_other_media_types_are_checked_too(
    client, tokens, inspection, runtime, media_type, data, phrase
):
    response = _upload(
        client,
        tokens["inspector"],
        inspection,
        data,
        name="f",
        kind="other",
        headers={"content-type": media_type},
    )
    assert response.status_code == 422 and phrase in response.json()["detail"]
    assert _stored_files(runtime) == []


def test_unknown_inspection_and_bad_kind(client, tokens, inspection, tmp_path):
    assert _upload(client, tokens["inspector"], 999, ply_bytes(tmp_path)).status_code == 404
    bad_kind = _upload(
        client, tokens["inspector"], inspection, ply_bytes(tmp_path), kind="Bad Kind!"
    )
    assert bad_kind.status_code == 422 and "kind" in bad_kind.json()["detail"]


def test_upload_idempotency_key_stores_one_copy(client, tokens, inspection, tmp_path, runtime):
    data = ply_bytes(tmp_path)
    headers = {**PLY, "Idempotency-Key": "scan-000"}
    first = _upload(client, tokens["inspector"], inspection, data, headers=headers)
    again = _upload(client, tokens["inspector"], inspection, data, headers=headers)
    assert first.status_code == again.status_code == 201 and first.json() == again.json()
    assert len(_stored_files(runtime)) == 1


def test_oversize_upload_is_413_whether_declared_or_streamed(tmp_path, sqlite_url, runtime_factory):
    settings = make_settings(tmp_path, sqlite_url, max_upload_mb=1)
    client, tokens, runtime = runtime_factory(settings)
    inspection = client.post(
        "/api/v1/inspections",
        json={"title": "t", "area": "cargo"},
        headers=auth(tokens["inspector"]),
    ).json()["id"]
    big = ply_bytes(tmp_path, plane_grid(400, 400))  # 1.9 MB
    declared = _upload(client, tokens["inspector"], inspection, big)
    assert declared.status_code == 413 and "1 MiB" in declared.json()["detail"]

    def chunks():
        for start in range(0, len(big), 65536):
            yield big[start : start + 65536]

    streamed = _upload(client, tokens["inspector"], inspection, chunks())
    assert streamed.status_code == 413
    assert _stored_files(runtime) == []


EIGHT_BIT_PNG = (
    b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x04\x00\x00\x00\x04\x08\x00\x00\x00\x00"
)
"""The start of a 4 × 4 8-bit grey PNG: its signature and IHDR chunk."""


@pytest.mark.parametrize(
    ("kind", "media_type", "data", "phrase"),
    [
        ("frames", "application/gzip", b"\x1f\x8b not really", "not a frame sequence"),
        ("frames", "application/zip", b"PK\x05\x06" + bytes(18), "needs at least 2 PNG frames"),
        ("model", "application/octet-stream", b"\x08\x07junk", "not a model vista can run"),
        ("trajectory", "text/plain", b"0 0 0 0 0 0 0 1\n0.1 1 2\n", "not a TUM trajectory"),
        ("image", "image/png", b"GIF89a not a png", "neither a PNG nor a JPEG"),
        ("depth", "image/png", EIGHT_BIT_PNG, "a depth map is 16-bit grey"),
        ("drive", "application/gzip", b"\x1f\x8b not really", "not a drive"),
    ],
)
def test_sequences_models_and_trajectories_are_checked(
    client, tokens, inspection, runtime, kind, media_type, data, phrase
):
    response = _upload(
        client,
        tokens["inspector"],
        inspection,
        data,
        name="f",
        kind=kind,
        headers={"content-type": media_type},
    )
    assert response.status_code == 422 and phrase in response.json()["detail"], response.text
    assert _stored_files(runtime) == []


def test_images_and_depth_maps_are_kept_with_their_size(client, tokens, inspection, tmp_path):
    import cv2
    import numpy as np

    depth = tmp_path / "d.png"
    cv2.imwrite(str(depth), np.full((6, 10), 2560, np.uint16))
    image = tmp_path / "i.jpg"
    cv2.imwrite(str(image), np.zeros((6, 10, 3), np.uint8))
    for path, kind, media_type, meta in (
        (depth, "depth", "image/png", {"width": 10, "height": 6}),
        (depth, "image", "image/png", {"width": 10, "height": 6}),
        (image, "image", "image/jpeg", {}),
    ):
        created = _upload(
            client,
            tokens["inspector"],
            inspection,
            path.read_bytes(),
            name=path.name,
            kind=kind,
            headers={"content-type": "application/octet-stream"},
        )
        assert created.status_code == 201, created.text
        assert created.json()["media_type"] == media_type and created.json()["meta"] == meta


def test_a_frame_sequence_is_kept_with_what_it_holds(client, tokens, inspection, tmp_path):
    from tests.sequences import pack, small_sequence

    archive = pack(small_sequence(tmp_path / "seq", seconds=0.05), tmp_path / "seq.tar.gz")
    created = _upload(
        client,
        tokens["inspector"],
        inspection,
        archive.read_bytes(),
        name="seq.tar.gz",
        kind="frames",
        headers={"content-type": "application/octet-stream"},
    )
    assert created.status_code == 201, created.text
    artifact = created.json()
    assert artifact["media_type"] == "application/gzip"
    assert artifact["meta"]["frames"] == 4 and artifact["meta"]["truth"] is True
    assert artifact["meta"]["camera"]["mm_per_px"] == 0.6
