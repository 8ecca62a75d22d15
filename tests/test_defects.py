"""Defect measurement against the simulator's ground truth (small assemblies; the accuracy
sweep at 0.1 mm spacing is `vista defects bench`)."""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from contract.tolerances import Limits, severity
from services.defects.config import ConfigError, MeasureConfig, parse_config
from services.defects.evaluate import evaluate
from services.defects.example import write_defects_example
from services.defects.measure import MeasureError, measure
from services.defects.report import result_document
from services.defects.simulate import (
    AssemblySpec,
    EdgeProfile,
    layout_to_part,
    panel_mesh,
    part_to_layout,
    random_assembly,
)
from services.defects.truth import Truth, seam_gap_mm
from services.lib.pointcloud import color
from services.lib.pointcloud.color import delta_e, lab_to_srgb, srgb_to_lab
from services.lib.pointcloud.ply import PointCloud, read_ply
from supervisor.cli import app


@pytest.fixture(scope="module")
def flat_example(tmp_path_factory):
    """A 2 × 2 flat assembly scanned every 0.2 mm, merged at the true poses."""
    out = tmp_path_factory.mktemp("flat")
    write_defects_example(out, AssemblySpec(), grid=(500, 770), seed=3)
    return out


def test_lab_round_trip_and_delta_e() -> None:
    lab = np.array([[86.0, 0.5, 6.0], [50.0, 20.0, -30.0]])
    back = srgb_to_lab(lab_to_srgb(lab))
    assert np.all(delta_e(back, lab) < 0.6)  # 8-bit quantisation only
    white = srgb_to_lab(np.array([255, 255, 255], np.uint8))
    assert np.allclose(white, [100, 0, 0], atol=0.01)


def test_lab_equals_the_numpy_formula() -> None:
    """The compiled steps of ``srgb_to_lab`` against the NumPy expressions they replaced:
    every 8-bit level (both sides of the linear toe) and block means in between. Not bit
    for bit: on CPUs with AVX-512, NumPy's power and cube root are SIMD routines whose last
    bit can differ from the C library's (seen: 1.7e-13 at most)."""
    rng = np.random.default_rng(2)
    levels = np.arange(256.0)[:, None].repeat(3, 1)
    means = rng.uniform(0, 255, (7, 5, 3)).astype(np.float32)
    for rgb in (levels, means, levels[:0]):
        c = np.asarray(rgb, dtype=np.float64) / 255.0
        linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        xyz = linear @ np.array(color._RGB_TO_XYZ).T / color._WHITE_D65
        f = np.where(xyz > color._EPSILON, np.cbrt(xyz), (color._KAPPA * xyz + 16) / 116)
        expected = np.stack(
            [116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])],
            -1,
        )
        np.testing.assert_allclose(srgb_to_lab(rgb), expected, rtol=1e-12, atol=1e-12)


def test_simulated_layout_is_exact() -> None:
    spec = AssemblySpec(rows=2, cols=3, radius_mm=1500.0)
    assembly = random_assembly(spec, np.random.default_rng(1))
    assert len(assembly.seams) == 7 and len(assembly.junctions) == 2
    assert all(len(seams) == 4 for _, seams in assembly.junctions)
    # layout ↔ part frame on the cylinder
    layout = np.array([[10.0, 40.0], [200.0, -30.0]])
    heights = np.array([1.5, -2.0])
    back, h = part_to_layout(assembly, layout_to_part(assembly, layout, heights))
    assert np.allclose(back, layout) and np.allclose(h, heights)
    # each seam's ends: the two panel edges are the gap apart there
    panels = {p.id: p for p in assembly.panels}
    for seam in assembly.seams:
        a, b = panels[seam.panels[0]], panels[seam.panels[1]]
        assert abs(a.height_mm - b.height_mm + seam.step_mm) < 1e-12
        gaps = seam_gap_mm(assembly, seam, np.array([0.0, 1.0]))
        assert np.all((gaps > 0.29) & (gaps < 6.01))
    # the rounded edge falls by the radius at the edge and not at all a radius inside
    edge = assembly.panels[0].edge
    heights = edge.height_mm(np.array([0.0, edge.size_mm, 5.0]))
    assert edge.kind == "round" and np.allclose(heights, [-edge.size_mm, 0.0, 0.0])


def test_edge_profiles_fall_to_the_side_face() -> None:
    """Square, chamfer and round profiles, and a burr standing on a square edge."""
    distance = np.array([0.0, 0.25, 0.5, 1.0, 2.0])
    chamfer = EdgeProfile("chamfer", 1.0, 45.0)
    assert np.allclose(chamfer.height_mm(distance), [-1.0, -0.75, -0.5, 0.0, 0.0])
    assert chamfer.depth_mm == pytest.approx(1.0) and chamfer.width_mm == 1.0
    square = EdgeProfile("square", 0.0, burr_mm=0.1, burr_width_mm=0.2)
    assert np.allclose(square.height_mm(distance), [0.1, 0.0, 0.0, 0.0, 0.0])
    assert square.depth_mm == 0.0 and 0.2 in square.samples_mm()
    assert len(EdgeProfile("round", 2.0).samples_mm()) >= 20
    with pytest.raises(ValueError, match="edge kind"):
        EdgeProfile("bevel")


def test_a_deep_edge_side_face_runs_down_below_its_foot() -> None:
    """A 5 mm arc on a 3 mm sheet: the side face starts at the arc's foot and runs down
    (a face folding back up into the edge would be seen from behind in a tilted view)."""
    from dataclasses import replace

    assembly = random_assembly(AssemblySpec(), np.random.default_rng(0))
    panel = replace(assembly.panels[0], edge=EdgeProfile("round", 5.0))
    vertices, _ = panel_mesh(assembly, panel)
    _, h = part_to_layout(assembly, vertices)
    assert assembly.thickness_mm < 5.0
    assert h.min() == pytest.approx(panel.height_mm - 6.0)
    assert np.isclose(h, panel.height_mm - 5.0).any()  # the arc's foot


def test_measures_gap_step_parallelism_and_mismatch_against_truth(flat_example) -> None:
    cloud = read_ply(flat_example / "cloud.ply")
    truth = Truth.from_document(json.loads((flat_example / "truth.json").read_text()))
    config = MeasureConfig()
    result = measure(cloud, config, threads=2)
    summary = evaluate(result, truth, config.tolerances).summary()
    assert summary["seams"] == "4/4 (+0 spurious)" and summary["junctions"] == "1/1"
    # The threads (the seams' and panels' order of work among them) change the time, not
    # the result: every seam, junction and surface finding, in the same order.
    one_thread = result_document(measure(cloud, config), config)
    two_threads = result_document(result, config)
    assert len(two_threads["findings"]) > len(two_threads["seams"])  # surface ones among them
    assert {**one_thread, "seconds": None} == {**two_threads, "seconds": None}
    assert summary["sections"] > 150
    # 0.2 mm spacing here; the 0.05 mm targets are for 0.1 mm (the bench)
    assert summary["gap_error_p95_mm"] < 0.05
    assert summary["step_error_p95_mm"] < 0.05
    assert summary["parallelism_error_max_mm"] < 0.05
    assert summary["mismatch_error_max_mm"] < 0.05
    for kind, counts in summary["geometric"].items():
        assert counts["fp"] == 0 and counts["fn"] == 0, (kind, counts)
    # the edges are found rounded, with the panels' radii
    radii = {round(p.edge.size_mm, 2) for p in truth.panels}
    measured = [e.radius_mm for s in result.seams for e in s.edges]
    assert all(e.model == "round" for s in result.seams for e in s.edges)
    assert all(min(abs(r - t) for t in radii) < 0.15 for r in measured)
    assert all(s.measured.all() for s in result.seams)


def test_a_seam_not_found_counts_its_sections_as_unmeasured(flat_example) -> None:
    """A seam lost with its panels merged (a coarse scan across a narrow gap) is no
    section measured: the evaluation counts the sections it would have had (its length
    over the pitch) as unmeasured, so a sweep's share measured cannot rise by losing seams."""
    cloud = read_ply(flat_example / "cloud.ply")
    truth = Truth.from_document(json.loads((flat_example / "truth.json").read_text()))
    config = MeasureConfig(surface=None)
    result = measure(cloud, config, threads=2)
    whole = evaluate(result, truth, config.tolerances).summary()
    lost = replace(result, seams=result.seams[1:])
    fewer = evaluate(lost, truth, config.tolerances).summary()
    length = result.seams[0].length_mm
    assert fewer["seams"] == "3/4 (+0 spurious)"
    assert abs(fewer["sections_total"] - whole["sections_total"]) <= 0.05 * length / 2 + 2
    assert fewer["unmeasured_share"] > whole["unmeasured_share"] + 0.15


def test_finds_every_surface_defect_without_false_alarms(flat_example) -> None:
    cloud = read_ply(flat_example / "cloud.ply")
    truth = Truth.from_document(json.loads((flat_example / "truth.json").read_text()))
    result = measure(cloud, MeasureConfig())
    summary = evaluate(result, truth, Limits()).summary()
    for kind, counts in summary["surface"].items():
        assert counts["fn"] == 0 and counts["fp"] == 0, (kind, counts)
    dents = [f for f in result.findings if f.type in ("dent", "bump")]
    true_dents = [d for d in truth.defects if d.type in ("dent", "bump")]
    for d in true_dents:
        near = min(dents, key=lambda f: np.linalg.norm(f.location - np.array(d.location)))
        assert abs(near.value - d.depth_mm) < 0.05 * d.depth_mm + 0.02
    colors = [f for f in result.findings if f.type == "color"]
    for d in (d for d in truth.defects if d.type == "color"):
        near = min(colors, key=lambda f: np.linalg.norm(f.location - np.array(d.location)))
        assert abs(near.value - d.delta_e) < 0.25 * d.delta_e


def test_result_document_follows_the_contract(flat_example) -> None:
    config = MeasureConfig()
    result = measure(read_ply(flat_example / "cloud.ply"), config)
    document = result_document(result, config)
    seam = document["seams"][0]
    assert {
        "id",
        "panels",
        "start",
        "end",
        "length_mm",
        "gap_mm",
        "step_mm",
        "parallelism_mm",
        "sections",
    } <= set(seam)
    assert set(seam["gap_mm"]) == {"min", "mean", "max"} and len(seam["start"]) == 3
    assert {"at", "gap_mm", "gap_sigma_mm", "step_mm", "edges", "residual_mm"} == set(
        seam["sections"][0]
    )
    assert seam["edges"][0]["model"] == "round" and seam["unmeasured"] is None
    assert {"at", "seams", "mismatch_mm"} <= set(document["junctions"][0])
    for defect in document["defects"]:
        assert {
            "type",
            "value_mm",
            "tolerance_mm",
            "location",
            "normal",
            "extent_mm",
            "severity",
            "confidence",
        } <= set(defect)
        assert defect["severity"] in ("minor", "major", "critical")
        assert abs(np.linalg.norm(defect["normal"]) - 1) < 1e-3
    json.dumps(document, allow_nan=False)


def test_tolerances_decide_what_is_a_defect(flat_example) -> None:
    cloud = read_ply(flat_example / "cloud.ply")
    lenient = parse_config(
        {
            "gap_mm": {"min": 0, "max": 50},
            "step_mm": {"max": 50},
            "parallelism_mm": {"max": 50},
            "mismatch_mm": {"max": 50},
            "surface": {"dent_depth_mm": 50, "scratch_depth_mm": 50, "color_delta_e": 100},
        }
    )
    result = measure(cloud, lenient)
    assert result.defects == [] and len(result.seams) == 4
    assert {f.severity for f in result.findings} == {"info"}
    assert (
        severity(0.6, 0.5, above=True) == "minor" and severity(1.2, 0.5, above=True) == "critical"
    )
    assert severity(0.2, 0.5, above=False) == "major" and severity(0.4, 0.5, above=True) == "info"


def test_a_measurement_within_two_sigma_of_its_limit_is_uncertain(flat_example) -> None:
    """Each seam measurement carries its 1σ; one within 2σ of its limit is neither a
    defect nor within tolerance: it is uncertain, listed with the advice its numbers give."""
    from services.defects.report import result_document

    cloud = read_ply(flat_example / "cloud.ply")
    steps = [f for f in measure(cloud, MeasureConfig()).findings if f.type == "step"]
    assert all(f.sigma_mm > 0 and abs(f.measurements.sigma_mm - f.sigma_mm) < 1e-4 for f in steps)
    step = min(steps, key=lambda f: abs(f.value))
    limit = round(abs(step.value) + 0.5 * step.sigma_mm, 4)  # half a σ above the value
    config = parse_config({"step_mm": {"max": limit}})
    result = measure(cloud, config)
    unsure = [f for f in result.uncertain if f.type == "step"]
    assert [f.source["seam"] for f in unsure] == [step.source["seam"]]
    assert unsure[0] not in result.defects and unsure[0].severity == "info"
    assert "re-scan at ≤" in unsure[0].measurements.advice
    document = result_document(result, config)
    assert [d["seam"] for d in document["uncertain"] if d["type"] == "step"] == [
        step.source["seam"]
    ]
    assert document["uncertain"][0]["tolerance_state"] == "uncertain"
    assert all(d["tolerance_state"] == "out" for d in document["defects"])


def test_config_errors_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"config.step_mm.max: Input should be greater than 0"):
        parse_config({"step_mm": {"max": -1}})
    with pytest.raises(ConfigError, match=r"config.gap: Extra inputs are not permitted"):
        parse_config({"gap": {"max": 1}})
    with pytest.raises(ConfigError, match=r"config.gap_mm: Value error, min \(2\) must be below"):
        parse_config({"gap_mm": {"min": 2, "max": 1}})
    with pytest.raises(ConfigError, match=r"min \(0.5\) must be below max \(0.3\) \(the default"):
        parse_config({"gap_mm": {"max": 0.3}})
    with pytest.raises(ConfigError, match=r"config.measurement.speed: Extra inputs are not"):
        parse_config({"measurement": {"speed": 2}})
    config = parse_config({"gap_mm": {"max": 4}, "measurement": {"pitch_mm": 5}})
    assert config.tolerances.gap_max_mm == 4 and config.tolerances.gap_min_mm == 0.5
    assert config.sections.pitch_mm == 5


def test_options_typed_override_the_config_files_settings(tmp_path) -> None:
    from services.defects.config import read_config
    from services.defects.kinds import MeasureParams

    path = tmp_path / "config.json"
    path.write_text(json.dumps({"step_mm": {"max": 0.3}, "measurement": {"pitch_mm": 5}}))
    options = MeasureParams(pitch_mm=3.0, slab_mm=2.0)
    tolerances, settings = read_config(path, options, {"slab_mm"})
    assert tolerances.step_mm.max == 0.3 and (settings.pitch_mm, settings.slab_mm) == (5, 2)
    assert read_config(None, options, {"slab_mm"})[1].pitch_mm == 3.0  # no file: the options
    with pytest.raises(ValueError, match="none.json: no such file"):
        read_config(tmp_path / "none.json", options, set())


def test_simulate_and_bench_are_the_services_verbs_and_the_old_spellings_hide() -> None:
    runner = CliRunner()
    for verb in ("measure", "simulate", "bench"):
        assert runner.invoke(app, ["defects", verb, "--help"]).exit_code == 0
    for group in ("simulate", "bench"):
        assert runner.invoke(app, [group, "defects", "--help"]).exit_code == 0
        assert "defects" not in runner.invoke(app, [group, "--help"]).output
    assert runner.invoke(app, ["measure", "--help"]).exit_code == 0


def test_a_cloud_without_panels_is_refused() -> None:
    rng = np.random.default_rng(0)
    spray = PointCloud(points=rng.uniform(0, 50, (5000, 3)).astype(np.float32))
    with pytest.raises(MeasureError, match="no panel top"):
        measure(spray, MeasureConfig())
    with pytest.raises(MeasureError, match="at least 1000"):
        measure(PointCloud(points=np.full((10, 3), np.nan, np.float32)), MeasureConfig())


def test_cli_measure_and_its_errors(flat_example, tmp_path) -> None:
    """`vista defects measure`: an option typed on the command line wins over CONFIG.json's
    setting; CONFIG.json's own settings are kept; errors name what is wrong."""
    runner = CliRunner()
    out = tmp_path / "result.json"
    config = json.loads((flat_example / "config.json").read_text())
    config["measurement"] |= {"max_gap_mm": 12.0, "edge_model": "auto"}
    (tmp_path / "config.json").write_text(json.dumps(config))
    done = runner.invoke(
        app,
        [
            "defects",
            "measure",
            str(flat_example / "cloud.ply"),
            "--config",
            str(tmp_path / "config.json"),
            "--max-gap-mm",
            "10",
            "-o",
            str(out),
            "--plot",
            str(tmp_path / "p.png"),
            "--truth",
            str(flat_example / "truth.json"),
        ],
    )
    assert done.exit_code == 0, done.output
    assert "4 seams, 1 junction;" in done.output and "against the truth" in done.output
    truth_part = done.output[done.output.index("against the truth") :]
    assert not re.search(r"\d\.\d{5,}", truth_part), "numbers rounded for reading"
    assert len(truth_part.splitlines()) <= 7, truth_part  # a summary; the rest in the file
    written = json.loads(out.read_text())
    assert written["seams"] and written["truth_evaluation"]["seams"].startswith("4/4")
    assert written["config"]["measurement"] == config["measurement"] | {"max_gap_mm": 10.0}
    assert (tmp_path / "p.png").stat().st_size > 10_000
    refused = runner.invoke(
        app,
        ["defects", "measure", str(flat_example / "cloud.ply"), "-o", str(out)]
        + ["--pitch-mm", "0.1"],
    )
    assert refused.exit_code == 2 and "--pitch-mm" in refused.output
    bad = tmp_path / "bad.json"
    bad.write_text('{"step_mm": {"max": "big"}}')
    failed = runner.invoke(
        app,
        ["defects", "measure", str(flat_example / "cloud.ply")]
        + ["--config", str(bad), "-o", str(out)],
    )
    assert failed.exit_code == 2 and "step_mm.max: Input should be a valid number" in failed.output
    missing = runner.invoke(app, ["measure", str(tmp_path / "none.ply"), "-o", str(out)])
    assert missing.exit_code == 2 and "none.ply" in missing.output  # the old spelling too
    truth = json.loads((flat_example / "truth.json").read_text())
    del truth["seams"][0]["step_mm"]
    (tmp_path / "truth.json").write_text(json.dumps(truth))
    untrue = runner.invoke(
        app,
        ["defects", "measure", str(flat_example / "cloud.ply"), "-o", str(out)]
        + ["--truth", str(tmp_path / "truth.json")],
    )
    assert untrue.exit_code == 2 and "not a truth document" in untrue.output
    assert "step_mm" in untrue.output


def test_bench_compares_with_the_gauge_against_truth(tmp_path) -> None:
    from services.defects.bench import SweepCase, run_defects_bench

    case = SweepCase("small", AssemblySpec(panel_mm=(110.0, 80.0)), spacing_mm=0.25)
    document = run_defects_bench(
        tmp_path / "defects.json", seeds=1, cases=(case,), sweeps=("assemblies",)
    )
    row = document["cases"][0]
    vista, gauge = row["vista"], row["gauge"]
    assert vista["sections"] > 100 and vista["gap_error_p95_mm"] < 0.05
    # the gauge's last-point edges sit on the rounded edge: its gaps are too wide
    assert gauge["gap_error_mean_mm"] > 5 * abs(vista["gap_error_mean_mm"]) + 0.05
    assert json.loads((tmp_path / "defects.json").read_text())["verdict"] == document["verdict"]


def test_edge_sweep_reports_unmeasured_sections_and_the_gauge(tmp_path) -> None:
    """The edge sweep at a small scale: square corners seen straight on are measured
    against truth; corners hidden in a step's shadow from a 30° view are left unmeasured,
    where the gauge reports a number."""
    from services.defects.bench import SweepCase, run_defects_bench

    spec = dict(panel_mm=(110.0, 80.0), edge_kinds=("square",), surface_defects=0)
    square = SweepCase(
        "square", AssemblySpec(**_spec(spec, gap_mm=(1.0, 3.0))), spacing_mm=0.2, yaw_deg=5.0
    )
    shadowed = SweepCase(
        "shadowed",
        AssemblySpec(**_spec(spec, gap_mm=(0.3, 0.5), step_mm=(-3.0, 3.0))),
        spacing_mm=0.2,
        yaw_deg=5.0,
        tilt_deg=30.0,
        field_mm=(154.0, 40.0),  # a line scanner: every point seen from 25–35°
    )
    document = run_defects_bench(  # seeds 100 and 101: two seams of the first are hidden
        tmp_path / "defects.json", seeds=1, sweeps=("edges",), edge_cases=(shadowed, square)
    )
    rows = {r["case"]: r for r in document["edge_cases"]}
    vista, gauge = rows["square"]["vista"], rows["square"]["gauge"]
    assert vista["edge_models"] == {"square": 8}
    # a 1 mm slab holds 5 rows at 0.2 mm spacing: a corner is placed within about a
    # quarter spacing (the 0.05 mm target is for 0.1 mm spacing, `vista defects bench`)
    assert vista["gap_error_p95_mm"] < 0.15 < gauge["gap_error_p95_mm"]
    assert vista["negative_gaps"] == 0 and vista["unmeasured_share"] < 0.05
    hidden = rows["shadowed"]["vista"]
    assert hidden["unmeasurable_sections"] > 20 and hidden["unmeasurable_flagged_share"] == 1.0
    assert rows["shadowed"]["gauge"]["gap_error_max_mm"] > 0.2  # the gauge reports them
    assert "edge sweep: no negative gap" in document["verdict"]


def _spec(base: dict, **override: object) -> dict:
    """An AssemblySpec's fields: ``base`` (``surface_defects=0``: none) and overrides."""
    fields = {k: v for k, v in {**base, **override}.items() if k != "surface_defects"}
    if base.get("surface_defects") == 0:
        fields.update(dents=0, bumps=0, scratches=0, patches=0)
    return fields


def test_sensor_artefacts_at_depth_jumps_and_tilted_views() -> None:
    """Mixed pixels fall between the two surfaces of a jump, spikes off it; elsewhere the
    returns are untouched. A tilted view still looks at the same point."""
    from services.defects.simulate import _tilted
    from services.lib.pointcloud.scan_sim import SensorModel, _edge_artefacts

    true = np.full((20, 30), 220.0)
    true[:, 15:] = 240.0  # a panel's edge over the backing, 20 mm farther
    rng = np.random.default_rng(0)
    mixed = SensorModel(grid=(20, 30), mixed_pixel_fraction=1.0)
    out = _edge_artefacts(true.ravel().copy(), true, mixed, rng).reshape(true.shape)
    at_jump = np.zeros(true.shape, bool)
    at_jump[:, 14:16] = True
    assert np.array_equal(out[~at_jump], true[~at_jump])
    assert ((out[at_jump] >= 220.0) & (out[at_jump] <= 240.0)).all()
    assert np.ptp(out[:, 14]) > 5  # anywhere between the surfaces
    spiky = SensorModel(grid=(20, 30), edge_spike_fraction=1.0)
    out = _edge_artefacts(true.ravel().copy(), true, spiky, rng).reshape(true.shape)
    offset = np.abs(out - true)[at_jump]
    assert ((offset >= 0.5) & (offset <= 5.0)).all()

    pose = np.eye(4)
    pose[:3, 3] = [100.0, 50.0, 220.0]
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down −z
    tilted = _tilted(pose, 30.0, 220.0)
    aim = pose[:3, 3] + 220.0 * pose[:3, 2]
    assert np.allclose(tilted[:3, 3] + 220.0 * tilted[:3, 2], aim)
    assert np.degrees(np.arccos(tilted[:3, 2] @ pose[:3, 2])) == pytest.approx(30.0)
    assert tilted[1, 2] > 0  # the view now runs towards +y as it descends


def test_which_edges_the_views_saw() -> None:
    """The truth of what can be measured: a corner 0.3 mm beyond a 3 mm step is out of
    sight of views tilted 30° across the step, its higher neighbour's is not; straight
    down, both are seen."""
    from dataclasses import replace

    from services.defects.example import BASE_T_PART
    from services.defects.simulate import AssemblyScanner, _tilted
    from services.lib.pointcloud.scan_sim import SensorModel, workplan

    spec = dict(rows=2, cols=1, panel_mm=(60.0, 40.0), edge_kinds=("square",), surface_defects=0)
    spec = AssemblySpec(**_spec(spec, gap_mm=(0.3, 0.3), taper_mm=(0.0, 0.0)))
    assembly = random_assembly(spec, np.random.default_rng(0))
    (seam,) = assembly.seams
    heights = {seam.panels[0]: 3.0, seam.panels[1]: 0.0}  # a (lower s) stands 3 mm higher
    panels = tuple(replace(p, height_mm=heights[p.id]) for p in assembly.panels)
    assembly = replace(assembly, panels=panels)
    sensor = SensorModel(grid=(40, 154), field_mm=(154.0, 40.0))
    scanner = AssemblyScanner(assembly, BASE_T_PART, sensor)
    straight = workplan(scanner.scanner.mesh, BASE_T_PART, sensor)
    tilted = np.stack([_tilted(p, 30.0, sensor.standoff_mm) for p in straight])
    along = np.linspace(0.1, 0.9, 9)
    assert scanner.edges_seen(straight, seam, along).all()
    seen = scanner.edges_seen(tilted, seam, along)
    assert seen[:, 0].all() and not seen[:, 1].any()


def test_limits_and_signs_read_one_way():
    """Both ends of a gap's range, a step's size either way with what its sign means, the
    others' upper limit — as the CLI, the demo and the dashboard show them."""
    from contract.tolerances import Limits, finding_line, limit_text, sign_text

    limits = Limits()
    assert limit_text("gap", limits) == "0.50–3.00 mm"
    assert limit_text("step", limits) == "|step| ≤ 0.50 mm"
    assert limit_text("dent", limits) == "≤ 0.20 mm" and limit_text("color", limits) == "≤ 3.0 ΔE"
    assert sign_text("step", -0.768, [0, 1]) == "P1 below P0"
    assert sign_text("step", 0.6, [2, 3]) == "P3 above P2" and sign_text("gap", 3.4, [0, 1]) == ""
    assert finding_line("step", -0.768, [0, 1], limits) == (
        "step          -0.768 mm (P1 below P0; limits |step| ≤ 0.50 mm)"
    )
    assert finding_line("color", 5.2, None, limits).endswith("ΔE (limits ≤ 3.0 ΔE)")


def test_pinholes_are_filled_and_one_cell_gaps_are_not() -> None:
    """A scan grid turned to the height map leaves single empty cells in a moiré, which
    would cut a panel's flat top into pieces; a gap one cell wide stays empty."""
    from services.defects.panels import _filled_pinholes

    height = np.zeros((12, 12), np.float32)
    height[3, 3] = height[8, 5] = np.nan  # pinholes
    height[:, 9] = np.nan  # a gap one cell wide
    filled = _filled_pinholes(height)
    assert filled[3, 3] == 0 and filled[8, 5] == 0
    assert np.isnan(filled[:, 9]).all()
    assert np.isnan(height[3, 3])  # the map itself is left as it was


def test_a_step_parts_a_coarse_map_where_no_gap_is_seen() -> None:
    """On a coarse map a gap the rows skip leaves no slope to see, but the tops either
    side of it stand at two heights: the two cells at a 0.3 mm step are marked, on a
    tilted plane and whichever way the step runs; the plane itself, a groove one cell
    wide (a scratch: its tops are level), and a step beside a gap seen (the edge's own
    business) are not."""
    from services.defects.panels import STEP_MM, _steps

    rows, cols = np.mgrid[0:40, 0:30]
    plane = (0.02 * rows - 0.015 * cols).astype(np.float32)
    flat = np.ones(plane.shape, bool)
    assert not _steps(plane, flat, STEP_MM).any()
    stepped = plane + np.where(cols >= 15, 0.3, 0.0).astype(np.float32)
    marked = _steps(stepped, flat, STEP_MM)
    assert marked[6:-6, 14:16].all() and not np.delete(marked, [14, 15], axis=1).any()
    across = plane + np.where(rows >= 20, -0.3, 0.0).astype(np.float32)
    assert _steps(across, flat, STEP_MM)[6:-6].any(axis=1).sum() == 2
    groove = plane - np.where(cols == 15, 0.3, 0.0).astype(np.float32)
    assert not _steps(groove, flat, STEP_MM).any()
    seen = flat.copy()
    seen[:, 15] = False  # the gap seen: its cells are not flat
    assert not _steps(stepped, seen, STEP_MM).any()


def test_a_dents_floor_takes_no_disc_out_of_a_coarse_top() -> None:
    """The step rule fires on a dent's floor (a raised cosine 0.6 mm deep and 12 mm
    across, on cells of 0.9 mm: a ring of cells), and each cell marked took a disc 13
    cells across out of the top with the 6-cell erosion — beside a gap, the top's edge
    over 20 mm, which growing back 6 cells did not restore. The cells at a step part the
    core ``STEP_REACH_CELLS`` either side: the top is one panel, grown back whole, while
    a 0.3 mm step still parts it in two."""
    from services.defects.panels import segment_panels
    from services.defects.raster import Raster, SurfaceFrame

    rows, cols = np.mgrid[0:80, 0:60] * 0.9
    r = np.hypot(rows - 24.0, cols - 10.0)
    dent = np.where(r < 6.0, -0.3 * (1 + np.cos(np.pi * r / 6.0)), 0.0).astype(np.float32)
    dent[:, :2] = np.nan  # a gap seen beside the dent, 8 mm from its centre
    for height, count in ((dent, 1), (dent + np.where(rows > 45, 0.3, 0.0), 2)):
        raster = Raster(
            SurfaceFrame(np.zeros(3), np.eye(3)),
            0.9,
            np.zeros(2),
            height.astype(np.float32),
            np.isfinite(height).astype(np.int32),
            np.zeros((1, 1), np.int32),
            None,
            np.zeros((0, 4), np.float32),
        )
        panels = segment_panels(
            raster, max_slope_deg=30, min_area_mm2=100, background_drop_mm=5, bridge_cells=6
        )
        assert panels.count == count
        top = panels.labels > 0
        assert top[12:34, 3:30].all()  # the dent's ring and the top's edge beside the gap


def test_a_seam_found_over_part_of_its_length_counts_the_rest_unmeasured() -> None:
    """A seam found over 28 of its 150 mm counted 14 of 14 sections measured: the rest of
    it, where a view saw both edges, now counts as sections not measured (every pitch,
    clear of the ends by ``END_ALLOWANCE_MM``); a seam found whole loses none."""
    from services.defects.evaluate import END_ALLOWANCE_MM, PITCH_MM, _sections_not_reached

    segment = np.array([150.0, 0.0, 0.0])
    part = np.arange(20.0, 48.1, PITCH_MM) / 150.0
    whole = np.arange(7.0, 143.1, PITCH_MM) / 150.0
    positions = np.arange(END_ALLOWANCE_MM, 150 - END_ALLOWANCE_MM, PITCH_MM)
    expected = len(positions) - 16  # those at 19…49 mm lie within a pitch of a section
    assert _sections_not_reached(part, segment, 0, None) == expected
    assert _sections_not_reached(whole, segment, 0, None) == 0
    assert _sections_not_reached(np.array([]), segment, 0, None) == expected + 16

    def unseen_beyond_100(seam_id: int, fraction: np.ndarray) -> np.ndarray:
        return np.repeat((fraction * 150.0 <= 100.0)[:, None], 2, axis=1)

    far = int((positions > 100).sum())
    assert _sections_not_reached(part, segment, 0, unseen_beyond_100) == expected - far


def test_spacing_sweep_reports_coverage_and_the_gauge(tmp_path) -> None:
    from services.defects.bench import (
        SweepCase,
        _angle_table,
        _one_phase,
        run_defects_bench,
        spacing_cases,
    )

    assert len(spacing_cases()) == 7 * 3 * 4 * 2  # spacings × edges × grid angles × noise
    case = SweepCase(
        "round 0.5 mm, grid 15°",
        AssemblySpec(panel_mm=(110.0, 80.0), edge_radius_mm=(1.0, 2.0)),
        spacing_mm=0.5,
        yaw_deg=15.0,
        edge="round",
    )
    document = run_defects_bench(
        tmp_path / "defects.json", seeds=1, sweeps=("spacing",), spacing_sweep=(case,)
    )
    row = document["spacing_cases"][0]
    vista, gauge = row["vista"], row["gauge"]
    assert row["grid_angle_deg"] == 15.0 and row["spacing_mm"] == 0.5
    # every section measured from the pooled profiles, the gap's σ honest
    assert vista["unmeasured_share"] < 0.05
    assert vista["gap_error_p95_mm"] < 0.1 < gauge["gap_error_p95_mm"]
    assert vista["sections_within_2sigma"] >= 0.9
    # the verdict pools every cell's sections per spacing, as the targets are set
    assert len(row["errors"]["gap_mm"]) == vista["sections"] > 0
    verdict = [key for key in document["verdict"] if key.startswith("spacing over 0.2 up to 0.5")]
    assert len(verdict) == 3 and all("at every spacing" in key for key in verdict)
    # by the grid's angle, and without the cells that sample a corner at one phase
    assert "| 0.5 | " in _angle_table([row]) and "15°" in _angle_table([row])
    assert not _one_phase(row)
    assert _one_phase(row | {"edge": "square", "grid_angle_deg": 45.0})
    assert _one_phase(row | {"edge": "chamfer", "grid_angle_deg": 0.0})
    assert not _one_phase(row | {"edge": "square", "grid_angle_deg": 2.0})


def test_the_measurement_page_shows_its_seams_sections_and_scene(flat_example, tmp_path) -> None:
    """measure_view: the seams' table (one row a seam, its sections measured and why not),
    each seam's cross-sections with the cloud's points across it — an empty band where
    the gap is, points on both sides — and thumbnails of the surface findings;
    measure_scene: the cloud within the budget with the outlines and seams."""
    from contract.views import CrossSections, JobFiles, Table, Thumbnails
    from services.defects.config import config_document
    from services.defects.report import result_document
    from services.defects.views import measure_scene, measure_view

    cloud_path = flat_example / "cloud.ply"
    config = MeasureConfig()
    result = measure(read_ply(cloud_path), config, threads=2)
    report = tmp_path / "defects.json"
    report.write_text(json.dumps(result_document(result, config)))
    files = JobFiles({"seams": 4}, {"defects.json": report}, {"cloud/cloud.ply": cloud_path})
    panels = measure_view(files)
    seams = next(p for p in panels if isinstance(p, Table) and p.title == "Seams")
    assert len(seams.rows) == 4 and "gap 0.50–3.00 mm" in seams.note
    sections = next(p for p in panels if isinstance(p, CrossSections))
    assert len(sections.seams) == 4
    for seam in sections.seams:
        measured = [s for s in seam["sections"] if s["gap_mm"] is not None]
        assert measured, seam["seam"]
        for section in measured[:3]:
            u = np.asarray(section["u_mm"])
            half = section["gap_mm"] / 2
            assert (u < -half).any() and (u > half).any()  # both panels' tops
            assert not (np.abs(u) < half - 0.3).any()  # nothing in the gap but its walls
    thumbs = next(p for p in panels if isinstance(p, Thumbnails))
    assert thumbs.findings and all(len(f["u_mm"]) > 50 for f in thumbs.findings)
    scene = measure_scene(files, 20_000)
    assert len(scene.points[0].points_mm) == 20_000
    assert {g.name for g in scene.lines} >= {"outlines", "seams"}
    assert config_document(config)["gap_mm"]["max"] == 3.0  # what the note reads
