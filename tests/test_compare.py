"""A scan against its nominal: every nominal format read to the same triangles and regions,
each alignment against the truth (20 % of the nominal unscanned, 5 % outliers), the
deviation findings of a dented plate with a mis-drilled hole, the command, and the
`defects.compare` job through the API — its findings judged, judged again when the
profile band changes, and carried when the part is compared again."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from pygltflib import GLTF2
from vista_client import Headset, VistaClient

from contract.tolerances import Limits, Tolerances, limits_of
from services.defects.align import AlignError, best_fit, given, pose_difference, reference_points
from services.defects.deviation import judge_deviation
from services.defects.nominal_parts import make_part
from services.lib.pointcloud.mesh_distance import TriangleMesh, index_mesh, signed_distance
from services.lib.pointcloud.nominal import NominalError, read_nominal
from services.lib.pointcloud.ply import PointCloud, write_ply
from services.lib.pointcloud.step import available as step_available
from services.lib.pointcloud.stl import write_stl
from services.lib.pointcloud.transforms import apply, from_rotvec
from tests.conftest import add_user, make_settings, wait_for
from tests.test_mesh_distance import box_mesh
from tests.test_scene_export import validate

VISTA = str(Path(__file__).resolve().parents[1] / ".venv" / "bin" / "vista")


def two_boxes() -> tuple[TriangleMesh, np.ndarray, tuple[str, ...]]:
    """Two closed boxes side by side, regions "left" and "right"."""
    box = box_mesh(np.array([10.0, 5.0, 2.0]))
    right = np.asarray(box.vertices_mm) + [30.0, 0.0, 0.0]
    vertices = np.vstack([box.vertices_mm, right])
    faces = np.vstack([box.faces, np.asarray(box.faces) + len(box.vertices_mm)])
    region = np.repeat([0, 1], len(box.faces))
    return TriangleMesh(vertices, faces), region, ("left", "right")


def _triangles(mesh: TriangleMesh) -> np.ndarray:
    """Each face's corners, rounded, in a canonical order (to compare meshes)."""
    corners = np.round(np.asarray(mesh.vertices_mm)[mesh.faces], 6)
    return np.array(sorted(map(lambda t: tuple(t.ravel()), corners)))


def _write_obj(path: Path, mesh: TriangleMesh, region: np.ndarray, names) -> None:
    lines = [f"v {x} {y} {z}" for x, y, z in np.asarray(mesh.vertices_mm)]
    for k, name in enumerate(names):
        lines.append(f"g {name}")
        lines += [f"f {a + 1}/1/1 {b + 1} {c + 1}" for a, b, c in mesh.faces[region == k]]
    path.write_text("\n".join(lines) + "\n")


def _write_glb(path: Path, mesh: TriangleMesh, region: np.ndarray, names) -> None:
    import trimesh

    scene = trimesh.Scene()
    for k, name in enumerate(names):
        part = trimesh.Trimesh(np.asarray(mesh.vertices_mm) / 1000.0, mesh.faces[region == k],
                               process=False)  # fmt: skip
        scene.add_geometry(part, geom_name=name, node_name=name)
    scene.export(path)


@pytest.mark.parametrize("kind", ["stl-ascii", "stl-binary", "obj", "ply", "glb"])
def test_every_mesh_format_reads_to_the_same_triangles_and_regions(kind, tmp_path):
    mesh, region, names = two_boxes()
    path = tmp_path / f"part.{kind.split('-')[0]}"
    if kind == "stl-ascii":
        write_stl(path, mesh, binary=False, region_of_face=region, regions=names)
    elif kind == "stl-binary":
        write_stl(path, mesh)
    elif kind == "obj":
        _write_obj(path, mesh, region, names)
    elif kind == "ply":
        write_ply(path, PointCloud(np.asarray(mesh.vertices_mm, np.float32)), faces=mesh.faces)
    else:
        _write_glb(path, mesh, region, names)
    nominal = read_nominal(path)
    assert np.allclose(_triangles(nominal.mesh), _triangles(mesh), atol=1e-5)
    whole = kind in ("stl-binary", "ply")  # formats without regions: one, "part"
    assert nominal.regions == (("part",) if whole else names)
    if not whole:  # each face kept its region
        centres = np.asarray(nominal.mesh.vertices_mm)[nominal.mesh.faces].mean(axis=1)
        assert (nominal.region_of_face == (centres[:, 0] > 15)).all()
    assert nominal.scale_to_mm == (1000.0 if kind == "glb" else 1.0)
    assert read_nominal(path, units_mm=2.0).mesh.vertices_mm.max() == pytest.approx(
        2 * (nominal.mesh.vertices_mm.max() / nominal.scale_to_mm), rel=1e-6
    )


@pytest.mark.skipif(not step_available(), reason="cadquery-ocp not installed (`make install`)")
def test_a_step_solid_is_tessellated_closed_and_outward_each_face_a_region(tmp_path):
    from services.defects.nominal_parts import part_shape
    from services.lib.pointcloud.step import write_step

    path = tmp_path / "plate.step"
    write_step(path, part_shape("plate"))
    nominal = read_nominal(path)
    assert nominal.format == "step" and len(nominal.regions) == 7  # six sides and the hole
    from services.lib.pointcloud.stl import mesh_report

    report = mesh_report(nominal.mesh)
    assert report.watertight and report.consistently_oriented
    probes = np.array([[0.0, 0.0, -2.5], [50.0, 0.0, 1.0], [50.0, 0.0, -1.0], [10.5, 0.0, -2.0]])
    found = signed_distance(nominal.mesh, probes).distance_mm
    # the hole's wall is a polygon within the chord (0.01 mm) of its circle
    assert found[0] == pytest.approx(10.0, abs=0.011)
    assert found[1:].tolist() == pytest.approx([1.0, -1.0, -0.5], abs=0.011)


@pytest.mark.skipif(not step_available(), reason="cadquery-ocp not installed (`make install`)")
def test_a_simulated_part_is_compared_with_its_cad_solid_by_its_reference_points(tmp_path):
    """What `vista defects simulate --part` writes, compared as its hint says: the STEP
    solid, aligned by the four reference points picked on the scan (0.05 mm picking
    error), within a tenth of a millimetre of the true pose, the dents found."""
    from services.defects.compare import compare_cloud
    from services.defects.kinds import CompareParams
    from services.defects.nominal_parts import write_part

    part = make_part("plate", seed=5, spacing_mm=1.0, warp_mm=0.0)
    written = {p.name: p for p in write_part(tmp_path, part)}
    params = CompareParams(
        align="points", reference_points=json.loads(written["points.json"].read_text())
    )
    band = Tolerances.model_validate({"profile_mm": {"max": 0.2}})
    compared = compare_cloud(written["cloud.ply"], written["nominal.step"], band, params, threads=2)
    gap_mm, angle_deg = pose_difference(compared.alignment.nominal_T_cloud, part.nominal_T_cloud,
                                        np.asarray(part.mesh.vertices_mm))  # fmt: skip
    assert gap_mm < 0.1 and angle_deg < 0.05
    peaks = [f["location"] for f in compared.document["defects"] if f["value"] < -0.2]
    for dent in part.dents:
        assert any(np.linalg.norm(np.subtract(at, dent.centre_mm)) < dent.radius_mm for at in peaks)


@pytest.mark.parametrize(
    ("name", "content", "said"),
    [
        ("empty.obj", b"# nothing\nv 0 0 0\n", "no face"),
        ("bad.glb", b"glTF\x02\x00\x00\x00garbage", "GLB"),
        ("cloud.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n", "no faces"),
        ("bad.step", b"ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\n#1=NOTHING();\nENDSEC;\nEND-ISO-10303-21;\n", "STEP"),
    ],
)  # fmt: skip
def test_a_file_that_is_no_nominal_is_refused_naming_why(tmp_path, name, content, said):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(NominalError, match=re.escape(said)):
        read_nominal(path)


@pytest.fixture(scope="module")
def angle():
    """The angle profile: its flange and web, with ends; 20 % of it unscanned, 5 % strays,
    dents, and the scan 3 mm and 2° away from the nominal."""
    return make_part("angle", seed=4, spacing_mm=0.8, warp_mm=0.0)


def test_a_best_fit_finds_the_pose_despite_unscanned_nominal_and_strays(angle):
    index = index_mesh(angle.mesh)
    vertices = np.asarray(angle.mesh.vertices_mm)
    fit = best_fit(index, angle.points_mm, np.eye(4), workers=2)  # from where the scan lies
    gap_mm, angle_deg = pose_difference(fit.nominal_T_cloud, angle.nominal_T_cloud, vertices)
    assert gap_mm < 0.02 and angle_deg < 0.005
    assert fit.moved_mm > 2.5 and fit.inlier_share < 0.97  # the strays weighed nothing
    assert max(fit.pose_sigma) < 0.01 and fit.residual_robust_mm < 0.02
    already = given(index, apply(fit.nominal_T_cloud, angle.points_mm))
    assert already.method == "given" and already.residual_robust_mm < 0.02


def test_the_principal_axes_start_a_fit_of_a_whole_scan_far_away():
    """Scanned whole, the angle is found from its principal axes (its scan 3 mm and 2° off
    in the scanner's frame); a fifth of it unscanned moves its centroid 50 mm along its
    length, where only its end says where it is — a start pose is needed then."""
    whole = make_part("angle", seed=4, spacing_mm=0.8, warp_mm=0.0, unscanned_share=0.0)
    fit = best_fit(index_mesh(whole.mesh), whole.points_mm, None, workers=2)
    gap_mm, angle_deg = pose_difference(
        fit.nominal_T_cloud, whole.nominal_T_cloud, np.asarray(whole.mesh.vertices_mm)
    )
    assert gap_mm < 0.02 and angle_deg < 0.005


def test_a_plane_alone_does_not_fix_the_pose_and_says_so():
    plane = TriangleMesh(np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0.0]]),
                         np.array([[0, 1, 2], [0, 2, 3]]))  # fmt: skip
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-40, 40, (2000, 2)), rng.normal(0, 0.01, 2000)])
    fit = best_fit(index_mesh(plane), points + [1.0, 2.0, 0.5], np.eye(4))
    assert fit.nominal_T_cloud[2, 3] == pytest.approx(-0.5, abs=0.005)  # its normal: fixed
    assert any("does not fix the pose along" in w for w in fit.warnings)


def test_reference_points_give_the_pose_and_each_pairs_residual():
    truth = from_rotvec(np.radians([1.0, -2.0, 30.0]), np.array([5.0, -3.0, 12.0]))
    nominal = {"A": [0, 0, 0], "B": [100, 0, 0], "C": [0, 50, 0], "D": [0, 0, 20]}
    scan_points = apply(np.linalg.inv(truth), np.array(list(nominal.values()), float))
    scan_points[3] += [0.0, 0.0, 0.05]  # D picked 0.05 mm off
    scan = dict(zip(nominal, scan_points.tolist(), strict=True))
    fit = reference_points(nominal, scan)
    gap_mm, angle_deg = pose_difference(
        fit.nominal_T_cloud, truth, np.array(list(nominal.values()), float)
    )
    assert gap_mm < 0.05 and angle_deg < 0.05
    assert [p["name"] for p in fit.pairs] == ["A", "B", "C", "D"]
    assert max(p["residual_mm"] for p in fit.pairs) == pytest.approx(
        next(p["residual_mm"] for p in fit.pairs if p["name"] == "D"))  # fmt: skip
    for nominal_points, scan_points, said in (
        ({"A": [0, 0, 0], "B": [1, 0, 0]}, {"A": [0, 0, 0], "B": [1, 0, 0]}, "at least 3 pairs"),
        (nominal, {**scan, "E": [0, 0, 0]}, "one side only: E"),
        ({k: [i, 0, 0] for i, k in enumerate("ABC")}, {k: [i, 0, 0] for i, k in enumerate("ABC")}, "one line"),
    ):  # fmt: skip
        with pytest.raises(AlignError, match=re.escape(said)):
            reference_points(nominal_points, scan_points)


def test_a_dented_plate_with_a_misdrilled_hole_gives_its_findings():
    plate = make_part("plate", seed=2, spacing_mm=0.6, warp_mm=0.0, dents=3)
    index = index_mesh(plate.mesh)
    aligned = apply(plate.nominal_T_cloud, plate.points_mm)  # a calibrated cell: given
    found = signed_distance(index, aligned, 2)
    known = np.isfinite(plate.deviation_mm)
    assert np.percentile(np.abs(found.distance_mm[known] - plate.deviation_mm[known]), 95) < 0.025
    limits = limits_of(Tolerances.model_validate({"profile_mm": {"max": 0.2}}))
    deviation = judge_deviation(aligned, found, plate.mesh, plate.region_of_face, plate.regions,
                                limits, sigma_mm=0.01)  # fmt: skip
    out = [f for f in deviation.findings if f.state == "out"]
    for dent in plate.dents:  # each dent deeper than the band found (two may be one area)
        near = [
            f
            for f in out
            if np.linalg.norm(f.at_mm - dent.centre_mm) < dent.radius_mm + f.extent_mm
        ]
        assert near and near[0].value_mm < -0.2 and near[0].severity != "info"
        peak = near[0]
        deepest = min(d.depth_mm for d in plate.dents
                      if np.linalg.norm(peak.at_mm - d.centre_mm) < d.radius_mm)  # fmt: skip
        assert peak.value_mm == pytest.approx(deepest, abs=0.03)
    hole = [f for f in out if np.linalg.norm(f.at_mm[:2]) < 12 and f.value_mm > 0]
    assert hole, "the material left where the nominal's hole is"
    stats = {r.name: r for r in deviation.regions}
    assert stats["top"].coverage_share == pytest.approx(0.8, abs=0.05)  # 20 % unscanned
    # the strays (5 % of the points, up to 5 mm off) make no finding: each is a dent or the hole
    explained = [
        f for f in out
        if np.linalg.norm(f.at_mm[:2]) < 12
        or any(np.linalg.norm(f.at_mm - d.centre_mm) < d.radius_mm for d in plate.dents)
    ]  # fmt: skip
    assert len(explained) == len(out)
    # and they are told apart as strays (alone, beyond twice the band): not in the statistics
    assert deviation.strays > 0.8 * 0.05 * len(plate.points_mm)
    assert stats["top"].sigma_mm < 0.1  # the dents, the noise; not the strays (σ 1 mm with them)


def test_a_regions_own_band_judges_its_findings():
    limits = limits_of(Tolerances.model_validate(
        {"profile_mm": {"min": -0.1, "max": 0.3, "regions": {"web": {"max": 1.0}}}}))  # fmt: skip
    assert limits.profile_band("flange") == (-0.1, 0.3)
    assert limits.profile_band("web") == (-1.0, 1.0)
    assert Limits().profile_band(None) == (-0.5, 0.5)
    for bad in ({"max": 0.2, "min": 0.1}, {"max": 0, "min": 0}, {"max": -1}):
        with pytest.raises(ValueError):
            Tolerances.model_validate({"profile_mm": bad})


def _write_plate(folder: Path, seed: int = 2) -> tuple[Path, Path]:
    plate = make_part("plate", seed=seed, spacing_mm=1.0, warp_mm=0.0, dents=2,
                      misalignment=(0.0, 0.0))  # fmt: skip
    cloud, nominal = folder / "plate.ply", folder / "plate.stl"
    write_ply(cloud, PointCloud(apply(plate.nominal_T_cloud, plate.points_mm).astype(np.float32)))
    write_stl(nominal, plate.mesh, binary=False, region_of_face=plate.region_of_face,
              regions=plate.regions)  # fmt: skip
    return cloud, nominal


def test_a_comparison_that_judged_little_or_nothing_does_not_read_as_a_pass(tmp_path):
    """The wrong nominal (nothing within 25 mm): refused, nothing compared. A scan mostly
    of something else, or too noisy for its band: compared, with warnings that say so."""
    from services.defects.compare import CompareError, compare_cloud
    from services.defects.kinds import CompareParams

    cloud, nominal = _write_plate(tmp_path)
    points = read_ply_points(cloud)
    given = CompareParams(align="given")
    band = Tolerances.model_validate({"profile_mm": {"max": 0.25}})
    far = tmp_path / "far.stl"
    box = box_mesh(np.array([10.0, 10.0, 10.0]))
    write_stl(far, TriangleMesh(np.asarray(box.vertices_mm) + 500.0, box.faces))
    with pytest.raises(CompareError, match="nothing was compared"):
        compare_cloud(cloud, far, band, given, threads=2)
    rng = np.random.default_rng(0)
    elsewhere = np.vstack([points, rng.uniform(-150, 150, (2 * len(points), 3)) + [0, 0, 400]])
    write_ply(tmp_path / "mixed.ply", PointCloud(elsewhere.astype(np.float32)))
    mixed = compare_cloud(tmp_path / "mixed.ply", nominal, band, given, threads=2)
    assert any("lies off the nominal" in w for w in mixed.document["warnings"])
    noisy = points + rng.normal(0, 0.3, points.shape)
    write_ply(tmp_path / "noisy.ply", PointCloud(noisy.astype(np.float32)))
    shaky = compare_cloud(tmp_path / "noisy.ply", nominal, band, given, threads=2)
    assert any("cannot be told from it" in w for w in shaky.document["warnings"])
    clean = compare_cloud(cloud, nominal, band, given, threads=2)
    assert clean.document["warnings"] == []
    # the residual is the judged points' (strays out), not the fit sample's with them
    assert clean.alignment.residual_rms_mm < 0.2  # the dents; with the strays it read 1.06 mm


def read_ply_points(path: Path) -> np.ndarray:
    from services.lib.pointcloud.ply import read_ply

    return read_ply(path).points.astype(np.float64)


def test_the_command_writes_the_result_the_cloud_the_regions_and_the_histogram(tmp_path):
    cloud, nominal = _write_plate(tmp_path)
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"profile_mm": {"max": 0.25}}))
    out = tmp_path / "result.json"
    done = subprocess.run(
        [VISTA, "defects", "compare", str(cloud), str(nominal), "-o", str(out), "--config",
         str(config), "--align", "best-fit", "--threads", "2"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    document = json.loads(out.read_text())
    assert document["alignment"]["method"] == "best-fit"
    assert document["profile_band_mm"] == [-0.25, 0.25]
    assert document["defects"] and all(d["type"] == "deviation" for d in document["defects"])
    assert "out of the profile band" in done.stdout and "aligned (best-fit)" in done.stdout
    from services.lib.pointcloud.ply import read_ply

    coloured = read_ply(out.with_suffix(".ply"))
    assert "deviation" in coloured.extra and coloured.colors is not None
    assert out.with_suffix(".regions.csv").read_text().startswith("region,points,")
    assert out.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"
    refused = subprocess.run(
        [VISTA, "defects", "compare", str(cloud), str(config), "-o", str(out)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert refused.returncode != 0 and "config.json" in refused.stderr + refused.stdout


def test_compared_through_the_api_judged_again_and_carried(start_server, tmp_path, sqlite_url):
    server = start_server(make_settings(tmp_path, sqlite_url, embedded_workers=1))
    token = add_user(server.app.state.runtime, "olga", "inspector", "olga-pw")
    client = VistaClient(server.url, token)
    inspection = client.create_inspection("bracket 12", "component",
                                          tolerances={"profile_mm": {"max": 0.25}})["id"]  # fmt: skip
    cloud, nominal = _write_plate(tmp_path)
    cloud_id = client.upload(inspection, cloud, kind="cloud")["id"]
    nominal_id = client.upload(inspection, nominal, kind="nominal")["id"]

    def compare() -> dict:
        run = client.create_run(inspection, [{"name": "compare", "kind": "defects.compare",
                                              "inputs": [cloud_id, nominal_id],
                                              "params": {"align": "given"}}])  # fmt: skip
        job = run["jobs"][0]
        done = wait_for(lambda: (j := client.job(job["id"]))["status"] in ("succeeded", "failed") and j,
                        timeout=300, what="the comparison")  # fmt: skip
        assert done["status"] == "succeeded", done
        return done

    first = compare()
    # its page: the alignment, the regions, the findings, the histogram
    view = client.request("GET", f"/jobs/{first['id']}/view").json()
    titles = [panel["title"] for panel in view["panels"]]
    assert titles[:2] == ["Comparison with the nominal", "Regions of the nominal"]
    assert "Deviations beyond the band" in titles and titles[-1] == "Deviation"
    regions = next(p for p in view["panels"] if p["title"] == "Regions of the nominal")
    assert [row[0] for row in regions["rows"]] == ["top", "edges", "hole"]
    # its scene: the coloured scan over the translucent nominal, valid glTF
    scene = tmp_path / "compare.glb"
    scene.write_bytes(client.request("GET", f"/jobs/{first['id']}/scene.glb").content)
    assert validate(scene)["issues"]["numErrors"] == 0
    gltf = GLTF2().load(str(scene))
    names = {node.name for node in gltf.nodes}
    assert {"deviation", "nominal"} <= names
    nominal = next(m for m in gltf.materials if m.name == "nominal")
    assert nominal.alphaMode == "BLEND"
    root = next(node for node in gltf.nodes if node.name.startswith("job-"))
    assert root.extras["deviation_scale_mm"] == [-0.25, 0.25]
    # the inspection's scene (the dashboard's and the headsets'): the scan as compared, its
    # nominal and the findings' rings, all in the nominal's frame
    whole = tmp_path / "inspection.glb"
    whole.write_bytes(client.request("GET", f"/inspections/{inspection}/scene.glb").content)
    assert validate(whole)["issues"]["numErrors"] == 0
    gltf = GLTF2().load(str(whole))
    names = {node.name for node in gltf.nodes}
    assert f"panels-{nominal_id}" in names and "marker-deviation" in {m.name for m in gltf.meshes}
    outputs = {a["name"]: a["id"] for a in client.artifacts(inspection)}
    assert gltf.asset.extras["cloud"]["artifact_id"] == outputs["deviation.ply"]
    found = list(client.defects(inspection, type="deviation"))
    assert len(found) == first["result"]["defects"] + first["result"]["uncertain"] > 0
    dent = min(found, key=lambda d: d["value_mm"])
    assert dent["value_mm"] < -0.25 and dent["tolerance_mm"] == -0.25
    assert dent["measurements"]["region"] == "top" and dent["measurements"]["area_mm2"] > 0
    client.judge(dent["id"], "confirmed", comment="a dent, 0.6 mm")
    # a headset syncs the deviations and the scene with the nominal, judges one offline
    admin = VistaClient(server.url, add_user(server.app.state.runtime, "ada", "admin", "ada-pw"))
    olga = next(u["id"] for u in admin.users() if u["username"] == "olga")
    headset = Headset(VistaClient(server.url, admin.create_token(olga, "hl2")), inspection)
    headset.sync()
    assert {d["type"] for d in headset.defects.values()} == {"deviation"}
    assert f"panels-{nominal_id}".encode() in headset.load_scene()
    other = next(i for i in headset.defects if i != dent["id"])
    headset.go_offline()
    headset.judge(other, "rejected", comment="the hole: drilled where the drawing says")
    headset.go_online()
    assert headset.push().sent == 1
    assert client.judgments(other)["judgments"][0]["verdict"] == "rejected"
    # a wider band: judged again, some now within it
    client.update_inspection(inspection, tolerances={"profile_mm": {"max": 5.0}})
    again = client.defect(dent["id"])
    assert again["severity"] == "info" and again["tolerance_mm"] == -5.0
    client.update_inspection(inspection, tolerances={"profile_mm": {"max": 0.25}})
    compare()  # the part compared again: the dent's line goes on, with its judgment
    current = [
        d for d in client.defects(inspection, type="deviation") if d["lineage_id"] == dent["id"]
    ]
    assert len(current) == 1 and current[0]["id"] != dent["id"]
    assert client.defect(dent["id"])["ended"] == "superseded"
    assert any(j["verdict"] == "confirmed" for j in client.judgments(current[0]["id"])["judgments"])
    client.close()
