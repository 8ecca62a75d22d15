"""STL nominals: binary and ASCII read back as written, a binary file that begins with
'solid' read as binary, damaged and oversized files refused with a sentence, and the
report a nominal's upload shows (closed, oriented, border, area)."""

from __future__ import annotations

import numpy as np
import pytest

from services.lib.pointcloud.mesh_distance import TriangleMesh
from services.lib.pointcloud.stl import StlError, mesh_report, read_stl, write_stl
from tests.test_mesh_distance import box_mesh

HALF = np.array([40.0, 25.0, 10.0])


def same_triangles(a: TriangleMesh, b: TriangleMesh) -> bool:
    def triangles(m: TriangleMesh) -> np.ndarray:
        corners = np.asarray(m.vertices_mm)[np.asarray(m.faces)]
        return corners[np.lexsort(corners.reshape(len(corners), -1).T[::-1])]

    return np.array_equal(triangles(a), triangles(b))


@pytest.mark.parametrize("binary", [True, False])
def test_a_box_reads_back_as_written(tmp_path, binary):
    box = box_mesh(HALF)
    path = tmp_path / "box.stl"
    write_stl(path, box, binary=binary)
    read = read_stl(path)
    assert len(read.vertices_mm) == 8 and same_triangles(read, box)
    report = mesh_report(read)
    assert report.watertight and report.consistently_oriented and report.border_edges == 0
    assert report.area_mm2 == pytest.approx(2 * (80 * 50 + 80 * 20 + 50 * 20))
    assert report.bounds_max_mm == (40.0, 25.0, 10.0)


def test_a_binary_stl_whose_header_says_solid_is_read_as_binary(tmp_path):
    path = tmp_path / "exported.stl"
    write_stl(path, box_mesh(HALF), name="solid part from a CAD exporter")
    assert path.read_bytes().startswith(b"solid")
    assert same_triangles(read_stl(path), box_mesh(HALF))


def test_an_open_or_flipped_mesh_is_reported_so(tmp_path):
    box = box_mesh(HALF)
    open_box = mesh_report(TriangleMesh(box.vertices_mm, box.faces[2:]))
    assert not open_box.watertight and open_box.border_edges == 4
    flipped = box.faces.copy()
    flipped[0] = flipped[0, ::-1]
    report = mesh_report(TriangleMesh(box.vertices_mm, flipped))
    assert report.watertight and not report.consistently_oriented


@pytest.mark.parametrize(
    ("content", "said"),
    [
        (b"", "neither a binary STL"),
        (b"PK\x03\x04" + b"\x00" * 200, "neither a binary STL"),
        (b"solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n vertex 1 0 0\n", "in threes"),
        (b"solid x\n vertex 0 0 0\n vertex 1 0 zero\n vertex 0 1 0\nendsolid", "not three numbers"),
        (b"solid x\n vertex 0 0 0\n vertex 1 0 nan\n vertex 0 1 0\nendsolid", "not a finite"),
    ],
)
def test_a_damaged_stl_is_refused_naming_why(tmp_path, content, said):
    path = tmp_path / "bad.stl"
    path.write_bytes(content)
    with pytest.raises(StlError, match=said):
        read_stl(path)


def test_a_truncated_binary_stl_is_not_read_as_one(tmp_path):
    path = tmp_path / "cut.stl"
    write_stl(path, box_mesh(HALF), name="part")
    path.write_bytes(path.read_bytes()[:-20])
    with pytest.raises(StlError, match="does not match the triangle count"):
        read_stl(path)


def test_more_triangles_than_allowed_are_refused_before_reading(tmp_path):
    path = tmp_path / "big.stl"
    write_stl(path, box_mesh(HALF))
    with pytest.raises(StlError, match="holds 12 triangles; at most 10"):
        read_stl(path, max_triangles=10)


def test_a_nominal_upload_is_checked_reported_and_scaled_to_mm(tmp_path):
    """`nominal` uploads as every kind: the STL read as a comparison will, what it is
    reported, metres scaled to millimetres (a copy kept), anything else a 422 sentence."""
    from supervisor.artifacts.validation import validate_upload
    from supervisor.problems import Problem

    stl = tmp_path / "part.stl"
    write_stl(stl, box_mesh(HALF / 1000.0))  # a CAD export in metres
    kept = validate_upload(
        stl, media_type="application/octet-stream", name="part.stl", kind="nominal", units="m"
    )
    assert kept.media_type == "model/stl" and kept.replacement is not None
    nominal = kept.meta["nominal"]
    assert nominal["watertight"] and nominal["consistently_oriented"]
    assert nominal["source_units"] == "m" and nominal["bounds_max_mm"] == pytest.approx(HALF)
    assert np.allclose(read_stl(kept.replacement).vertices_mm.max(axis=0), HALF, atol=1e-5)
    open_sheet = TriangleMesh(box_mesh(HALF).vertices_mm, box_mesh(HALF).faces[:2])
    write_stl(stl, open_sheet, binary=False)
    as_is = validate_upload(
        stl, media_type="application/octet-stream", name="part.stl", kind="nominal"
    )
    assert as_is.replacement is None and as_is.meta["nominal"]["border_edges"] == 4
    stl.write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    with pytest.raises(Problem) as refused:
        validate_upload(stl, media_type="application/octet-stream", name="x.stl", kind="nominal")
    assert refused.value.status == 422 and "is not a nominal model" in refused.value.detail


def test_a_nominal_in_metres_uploads_through_the_api_as_millimetres(client, tokens, tmp_path):
    """As a user sends it: POST …/artifacts?kind=nominal&units=m keeps part.stl in mm, the
    file sent named in its metadata; the download reads back at the part's true size."""
    from tests.conftest import auth

    headers = auth(tokens["inspector"])
    inspection = client.post(
        "/api/v1/inspections", json={"title": "bracket", "area": "wing"}, headers=headers
    ).json()["id"]
    sent = tmp_path / "part.stl"
    write_stl(sent, box_mesh(HALF / 1000.0))
    answer = client.post(
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": "nominal", "name": "part.stl", "units": "m"},
        content=sent.read_bytes(),
        headers={**headers, "Content-Type": "model/stl"},
    )
    assert answer.status_code == 201, answer.text
    stored = answer.json()
    assert stored["name"] == "part.stl" and stored["media_type"] == "model/stl"
    assert stored["meta"]["nominal"]["area_mm2"] == pytest.approx(2 * (80 * 50 + 80 * 20 + 50 * 20))
    assert stored["meta"]["source"]["name"] == "part.stl"
    got = tmp_path / "got.stl"
    got.write_bytes(
        client.get(
            f"/api/v1/inspections/{inspection}/artifacts/{stored['id']}/content", headers=headers
        ).content
    )
    assert np.allclose(read_stl(got).vertices_mm.max(axis=0), HALF, atol=1e-4)
