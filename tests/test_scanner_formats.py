"""Scanners' own cloud formats, each written by another library than vista's writer: read
by content, converted to millimetres with grids, colour and intensity kept, and converted
at the upload into vista's PLY (its source's format and unit named)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from services.lib.pointcloud.ply import read_ply
from services.lib.pointcloud.scanner import ScannerFormatError, read_cloud, sniff
from tests import scannerfiles as sf
from tests.conftest import auth, make_settings

OCTET = {"content-type": "application/octet-stream"}
CASES = {
    # name: (writer, format, grid kept, colour kept, intensity kept, coordinate tolerance mm)
    "scan.ply": (sf.write_ply_ascii_open3d, "ply-ascii", False, True, False, 1e-4),
    "grid.ply": (sf.write_ply_big_endian, "ply-big-endian", True, False, True, 1e-4),
    "scan.pcd": (sf.write_pcd, "pcd", True, True, True, 1e-4),
    "scan.las": (lambda p, t: sf.write_las(p, t, compressed=False), "las", False, True, True, 0.06),
    "scan.laz": (lambda p, t: sf.write_las(p, t, compressed=True), "laz", False, True, True, 0.06),
    "scan.e57": (sf.write_e57, "e57", True, True, True, 1e-4),
    "scan.xyz": (sf.write_xyz, "xyz", False, True, False, 1e-4),
    "scan.pts": (sf.write_pts, "pts", False, True, True, 1e-3),
}


@pytest.mark.parametrize("name", list(CASES))
def test_each_format_reads_as_its_writer_wrote_it(tmp_path: Path, name: str):
    write, fmt, grid, colour, intensity, tolerance_mm = CASES[name]
    truth = sf.truth()
    path = tmp_path / name
    write(path, truth)
    assert sniff(path) == fmt
    converted = read_cloud(path)
    cloud = converted.cloud
    assert converted.format == fmt and not converted.units_given
    keep = sf.measured(truth)
    expected_mm = truth.points_m * 1000.0
    if grid:
        assert cloud.grid_shape == (sf.HEIGHT, sf.WIDTH)
        assert np.isnan(cloud.points[list(sf.HOLES)]).all()  # unmeasured pixels stay NaN
        points, colors, values = cloud.points[keep], cloud.colors, cloud.intensity
        colors = None if colors is None else colors[keep]
        values = None if values is None else values[keep]
    else:
        assert cloud.grid_shape is None and len(cloud.points) == keep.sum()
        points, colors, values = cloud.points, cloud.colors, cloud.intensity
    shifted = expected_mm[keep] + (sf.UTM_M * 1000.0 if fmt in ("las", "laz") else 0.0)
    shifted = shifted - np.asarray(converted.origin_shift_mm)
    assert np.abs(points - shifted).max() < tolerance_mm
    if fmt in ("las", "laz"):  # 500 km away: shifted by whole metres, float32 keeps 0.1 mm
        assert converted.origin_shift_mm == (512_345_000.0, 5_401_234_000.0, 310_000.0)
    assert (colors is not None) == colour
    if colour:
        assert np.array_equal(colors, truth.colors[keep])
    assert (values is not None) == intensity
    if intensity:
        scale = 1 / 100.0 if fmt == "e57" else 1.0
        assert np.allclose(values, truth.intensity[keep] * scale, atol=1e-4)


def test_units_named_by_the_sender_and_files_that_are_not_clouds(tmp_path: Path):
    truth = sf.truth()
    pcd = tmp_path / "scan.pcd"
    sf.write_pcd(pcd, truth)
    assert read_cloud(pcd).units == "m"
    in_mm = read_cloud(pcd, units="mm")
    assert in_mm.units_given and np.nanmax(in_mm.cloud.points[:, 2]) < 1.0  # taken as is
    e57 = tmp_path / "scan.e57"
    sf.write_e57(e57, truth)
    with pytest.raises(ScannerFormatError, match="metres by its standard"):
        read_cloud(e57, units="mm")
    with pytest.raises(ScannerFormatError, match="units 'furlong'"):
        read_cloud(pcd, units="furlong")
    text = tmp_path / "notes.txt"
    text.write_text("gap 1 2\nstep 3 4\n")
    assert sniff(text) is None
    with pytest.raises(ScannerFormatError, match="is not a point cloud vista reads"):
        read_cloud(text)
    wide = tmp_path / "wide.xyz"
    wide.write_text("1 2 3 4 5\n6 7 8 9 10\n")
    with pytest.raises(ScannerFormatError, match="rows of 5 numbers"):
        read_cloud(wide)
    damaged = tmp_path / "damaged.e57"
    damaged.write_bytes(e57.read_bytes()[:2000])
    with pytest.raises(ScannerFormatError, match="is not a readable E57 file"):
        read_cloud(damaged)


def test_upload_converts_a_scanners_file_and_names_its_source(
    runtime_factory, tmp_path, sqlite_url
):
    client, tokens, runtime = runtime_factory(make_settings(tmp_path, sqlite_url))
    token = tokens["inspector"]
    inspection = client.post(
        "/api/v1/inspections", json={"title": "t", "area": "cabin"}, headers=auth(token)
    ).json()["id"]
    url = f"/api/v1/inspections/{inspection}/artifacts"
    truth = sf.truth()
    e57 = tmp_path / "wing.e57"
    sf.write_e57(e57, truth)

    kept = client.post(
        url, params={"kind": "cloud", "name": "wing.e57"}, content=e57.read_bytes(),
        headers={**auth(token), **OCTET},
    )  # fmt: skip
    assert kept.status_code == 201, kept.text
    body = kept.json()
    assert (body["name"], body["media_type"]) == ("wing.ply", "application/x-ply")
    assert body["meta"]["source"]["format"] == "e57" and body["meta"]["source"]["units"] == "m"
    assert body["meta"]["ply"]["grid_shape"] == [sf.HEIGHT, sf.WIDTH]
    stored = client.get(f"{url}/{body['id']}/content", headers=auth(token))
    assert stored.status_code == 200
    copy = tmp_path / "copy.ply"
    copy.write_bytes(stored.content)
    cloud = read_ply(copy)
    keep = sf.measured(truth)
    assert np.abs(cloud.points[keep] - truth.points_m[keep] * 1000.0).max() < 1e-3

    xyz = tmp_path / "wing.xyz"
    sf.write_xyz(xyz, truth)
    in_m = client.post(
        url, params={"kind": "cloud", "name": "wing-m.xyz", "units": "m"},
        content=xyz.read_bytes(), headers={**auth(token), **OCTET},
    )  # fmt: skip
    assert in_m.status_code == 201, in_m.text
    assert in_m.json()["meta"]["source"] == {
        "format": "xyz",
        "format_name": "XYZ/ASC text",
        "units": "m",
        "units_assumed": False,
        "origin_shift_mm": [0.0, 0.0, 0.0],
        "dropped_points": 0,
        "name": "wing-m.xyz",  # the file sent, as sent
        "size_bytes": xyz.stat().st_size,
        "sha256": hashlib.sha256(xyz.read_bytes()).hexdigest(),
    }
    assert in_m.json()["meta"]["ply"]["bounds_max_mm"][2] == pytest.approx(665_000.0, rel=1e-6)

    for params, content, words in (
        ({"kind": "report", "name": "a.json", "units": "m"}, b"{}", "units apply to point"),
        ({"kind": "cloud", "name": "n.txt"}, b"gap 1 2\nstep 3 4\n", "nor is it a PCD"),
        ({"kind": "cloud", "name": "d.e57"}, e57.read_bytes()[:3000], "not a readable E57"),
    ):
        refused = client.post(url, params=params, content=content, headers={**auth(token), **OCTET})
        assert refused.status_code == 422 and words in refused.json()["detail"], refused.text
    listed = client.get(url, headers=auth(token)).json()["items"]
    assert sorted(a["name"] for a in listed) == ["wing-m.ply", "wing.ply"]
    assert list((runtime.storage.root / "tmp").iterdir()) == []  # no upload nor conversion left


REAL_SCAN = (
    Path(__file__).resolve().parents[2] / "shared/data/kitti-raw-2011_09_26/velodyne/0000000000.bin"
)


@pytest.mark.skipif(not REAL_SCAN.exists(), reason="../shared/data's KITTI raw drive is not here")
@pytest.mark.parametrize("fmt", ["laz", "pcd"])
def test_a_real_velodyne_scan_through_a_survey_format(tmp_path: Path, fmt: str):
    """A real sensor's scan (KITTI's Velodyne HDL-64E: sparse rings, 120 m across, not our
    simulator's dense grid) written by laspy or pypcd4 reads back in mm to the writer's
    resolution, its reflectance kept as intensity."""
    import laspy
    from pypcd4 import PointCloud as Pcd

    scan = np.fromfile(REAL_SCAN, dtype="<f4").reshape(-1, 4)
    path = tmp_path / f"velodyne.{fmt}"
    if fmt == "laz":
        header = laspy.LasHeader(point_format=1, version="1.4")
        header.offsets, header.scales = np.floor(scan[:, :3].min(axis=0)), [0.001] * 3
        las = laspy.LasData(header)
        las.x, las.y, las.z = scan[:, :3].T.astype(np.float64)
        las.intensity = np.round(scan[:, 3] * 1000).astype(np.uint16)
        las.write(str(path), laz_backend=laspy.LazBackend.Lazrs)
    else:
        Pcd.from_xyzi_points(scan).save(path)
    converted = read_cloud(path)
    assert converted.format == fmt and converted.units == "m" and converted.dropped_points == 0
    cloud = converted.cloud
    assert cloud.grid_shape is None and len(cloud.points) == len(scan)
    resolution_mm = 0.5 if fmt == "laz" else 0.01  # LAS's 1 mm steps; float32 metres
    assert np.abs(cloud.points - scan[:, :3] * 1000.0).max() <= resolution_mm
    expected = np.round(scan[:, 3] * 1000) if fmt == "laz" else scan[:, 3]
    assert np.allclose(cloud.intensity, expected, atol=1e-6)
