"""Gap and step on every kind of edge, the self-checks that leave a section unmeasured,
and the panels' places and the step's sign rule — on clouds made without the project's
simulator (``edgeclouds``)."""

from __future__ import annotations

import json
from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from typer.testing import CliRunner

from contract.tolerances import advice
from services.defects import measure as measure_module
from services.defects.config import ConfigError, MeasureConfig, parse_config
from services.defects.edges import MODELS
from services.defects.measure import MeasureResult, SeamResult, measure
from services.defects.report import result_document
from services.lib.pointcloud.ply import PointCloud, write_ply
from supervisor.cli import app
from tests.edgeclouds import seam_cloud

CONFIG = replace(MeasureConfig(), surface=None)


@cache
def _measured(gap: float, step: float, a: tuple, b: tuple, **kw: float) -> MeasureResult:
    return measure(seam_cloud(gap, step, a, b, **kw), CONFIG)


def _one_seam(result: MeasureResult) -> SeamResult:
    assert len(result.seams) == 1, [s.panels for s in result.seams]
    return result.seams[0]


# The table (true gap / step; what vista reported before) and more.
EDGES = [
    (2.0, 0.8, ("square", 0), ("square", 0), ("square", "square")),  # was −4.377
    (0.7, 0.3, ("square", 0), ("square", 0), ("square", "square")),  # was −5.628
    (2.5, 0.5, ("square", 0), ("round", 2.0), ("square", "round")),  # was −0.681
    (2.0, 0.3, ("chamfer", 1.0), ("chamfer", 1.0), ("chamfer", "chamfer")),
    (1.5, 0.4, ("chamfer", 0.3), ("chamfer", 0.3), ("chamfer", "chamfer")),
    (2.0, 0.3, ("round", 1.0), ("round", 1.0), ("round", "round")),
    (3.0, 0.0, ("round", 4.0), ("round", 4.0), ("round", "round")),  # was 4.884
    (1.0, -0.6, ("round", 0.3), ("chamfer", 0.6), ("round", "chamfer")),
]


@pytest.mark.parametrize(("gap", "step", "a", "b", "models"), EDGES)
def test_gap_and_step_on_every_edge_type(gap, step, a, b, models) -> None:
    seam = _one_seam(_measured(gap, step, a, b))
    assert [e.model for e in seam.edges] == list(models)
    assert seam.measured.mean() > 0.95, seam.sections_unmeasured
    gaps = seam.sections_gap_mm[seam.measured]
    assert np.percentile(np.abs(gaps - gap), 95) < 0.05
    assert gaps.min() > 0
    steps = seam.sections_step_mm[np.isfinite(seam.sections_step_mm)]
    assert np.percentile(np.abs(steps - step), 95) < 0.05
    for edge, (kind, size) in zip(seam.edges, (a, b), strict=True):
        if kind == "round":
            assert abs(edge.radius_mm - size) < 0.1 * size + 0.03
        if kind == "chamfer":
            assert abs(edge.angle_deg - 45.0) < 3.0
    # each section says which models it used and how well they fit
    assert set(np.unique(seam.sections_models)) <= set(range(len(MODELS)))
    assert np.nanmax(seam.sections_residual_mm) < 2.5 * seam.noise_mm
    assert abs(seam.noise_mm - 0.02) < 0.005  # estimated from the data


# Issue 54: coarse scanners. (spacing, grid angle to the seam, the edges, error p95 bound).
COARSE = [
    (0.3, 3.0, ("square", 0), ("square", 0), 0.05),  # was 0 of 45 sections at 0.3 mm
    (0.5, 15.0, ("square", 0), ("round", 2.0), 0.10),
    (0.5, 3.0, ("round", 1.5), ("round", 1.0), 0.05),
    (1.0, 15.0, ("round", 2.0), ("round", 2.0), 0.20),
    # Rows 2° off the seam: their phases drift by a spacing only over 30 of them; slabs
    # widened until they drift through every phase place the corner finely (p95 0.033 mm;
    # 0.3 mm or so with slabs widened only to 0.4 spacings).
    (1.0, 2.0, ("square", 0), ("square", 0), 0.10),
    # Rows exactly along the seam: every profile samples the corner at one phase, which no
    # pooling refines; the corner is placed within a spacing, σ s/√12 per side (it was
    # left unmeasured: a 1.5 mm band held one column, the top 'continued past a hole').
    (1.0, 0.0, ("square", 0), ("square", 0), 0.75),
]


@pytest.mark.parametrize(("spacing", "yaw", "a", "b", "bound"), COARSE)
def test_coarse_clouds_measure_from_many_profiles_with_an_honest_sigma(
    spacing, yaw, a, b, bound
) -> None:
    """A coarse cloud's sections pool the profiles of a slab many spacings thick, each
    side's edge followed along it, so their phases sample the edge finely together; each
    gap's 1σ covers its error."""
    gap, step = 2.3, 0.4  # the corners between columns of a grid along the seam
    seam = _one_seam(_measured(gap, step, a, b, spacing_mm=spacing, yaw_deg=yaw))
    assert seam.measured.mean() >= 0.9, seam.sections_unmeasured
    errors = seam.sections_gap_mm[seam.measured] - gap
    assert np.percentile(np.abs(errors), 95) <= bound
    sigma = seam.sections_gap_sigma_mm[seam.measured]
    assert np.mean(np.abs(errors) <= 2 * sigma) >= 0.9
    steps = seam.sections_step_mm[np.isfinite(seam.sections_step_mm)]
    assert np.percentile(np.abs(steps - step), 95) <= bound


@pytest.mark.parametrize(
    ("edge", "spacing"),
    [
        (("chamfer", 1.0), 0.5),
        (("round", 1.5), 0.5),
        (("round", 0.8), 0.5),  # an arc fitted to a chamfer's two columns: 81 % within 2σ
        (("chamfer", 1.0), 1.0),  # wholly unmeasured: the fits started at the top's end
        (("round", 1.5), 1.0),  # wholly unmeasured
    ],
)
def test_a_coarse_grid_along_the_seam_never_claims_what_it_cannot_see(edge, spacing) -> None:
    """A chamfer or an arc sampled at 0.5 or 1 mm by rows along the seam: one or two
    columns of points on it, all at one phase, anywhere up to a spacing past the top's last
    point. The fits start where those points place the edge (``edges.implied_corner``), so
    the seam is measured; its shape is barely pinned — a column on a chamfer, all at one
    depth, once passed for a side face seen (σ 0.003 mm on a 0.5 mm error), and an arc fits
    a chamfer's two columns as well as a chamfer does — so each edge is placed to within
    a stretch either way (σ s/√3) and every gap measured lies within 2σ of the truth."""
    gap = 2.3
    seam = _one_seam(_measured(gap, 0.4, edge, edge, spacing_mm=spacing, yaw_deg=0.0))
    assert seam.measured.mean() >= 0.9, seam.sections_unmeasured
    errors = seam.sections_gap_mm[seam.measured] - gap
    sigma = seam.sections_gap_sigma_mm[seam.measured]
    assert np.mean(np.abs(errors) <= 2 * sigma) >= 0.9, (errors, sigma)


def test_an_edge_between_two_samples_is_placed_by_what_the_samples_allow() -> None:
    """A top whose last point (u = 0) has no point below it beyond, the next sample 0.75 mm
    on (in the gap, or where an arc is too steep to return a point): a square corner
    stands in that stretch; an arc of radius ρ starts where the top's last point leaves
    it by 3σ at most, and ends at a slope of 60° at most at the next sample — so a 1 mm
    arc's side face lies 0.65–0.88 mm out, where a corner's extent (0.375) put it. Any
    shape (``bare_extent``) covers both, and a radius the points contradict (5 mm: it
    would have shown below the top) places nothing."""
    from services.defects.edges import arc_extent, bare_extent, extent

    u = np.repeat(np.arange(-3.0, 0.01, 0.75), 10)
    d = np.random.default_rng(0).normal(0.0, 0.02, u.shape)
    square, square_sigma = extent(u, d, 0.02, 0.75)
    assert square == pytest.approx(0.375, abs=0.01)
    x, sigma = arc_extent(u, d, 0.02, 0.75, 1.0)
    low, high = 1.0 - np.sqrt(6 * 1.0 * 0.02), 0.75 + 1.0 * (1 - np.sin(np.radians(60)))
    assert x == pytest.approx((low + high) / 2, abs=0.01)
    assert sigma == pytest.approx((high - low) / np.sqrt(12), abs=0.005)
    assert np.isnan(arc_extent(u, d, 0.02, 0.75, 5.0)[0])
    any_x, any_sigma = bare_extent(0.0, 0.75, 0.02)
    for truth in (0.0, 0.75, x):  # a corner at either end of the stretch, the 1 mm arc
        assert abs(any_x - truth) <= 2 * any_sigma


def test_a_coarse_round_edged_assembly_along_the_rows_is_measured_where_it_is_seen() -> None:
    """The spacing sweep's rounded edges (0.2–5 mm) at 0.75 mm, rows along the seams: a
    seam's chamfer could not follow three points on another section's arc, an arc fell
    between two samples, a bare top end was refused for a σ over 0.05 mm — 29 % of the
    sections were measured. Each section now takes the model that explains it (or the
    extent its points allow): most are measured, with a σ that holds."""
    from services.defects.bench import _run, spacing_cases

    case = spacing_cases((0.75,), (0.0,), (0.02,), ("round",))[0]
    vista, _ = _run(case, 336, threads=1, timed_runs=1)
    summary = vista.summary()
    assert summary["unmeasured_share"] < 0.4
    assert summary["sections_within_2sigma"] >= 0.9


def test_arcs_sampled_at_one_phase_claim_no_finer_than_a_share_of_the_stretch() -> None:
    """Rounded edges (0.2–5 mm) at 0.2 mm, rows at 45° to the seams (the spacing sweep's
    cell): the same few places on each arc in every section bias its fit alike — 0.89 of
    the sections were within 2σ, their σ from the fit's noise alone. An arc is placed no
    finer than ``SHAPE_PHASE`` of the stretch its profiles leave."""
    from services.defects.bench import _run, spacing_cases

    case = spacing_cases((0.2,), (45.0,), (0.02,), ("round",))[0]
    vista, _ = _run(case, 270, threads=1, timed_runs=1)
    assert vista.summary()["sections_within_2sigma"] >= 0.95
    assert vista.summary()["gap_error_p95_mm"] <= 0.11


def test_an_arc_is_placed_no_finer_than_a_share_of_its_radius() -> None:
    """Rounded edges of 3.5 and 4 mm at 0.05 mm, grid 2°: the radius a seam's sections
    share carries their common error, which their noise does not show — a sixth of the
    sections lay beyond 2σ (σ 0.0035 mm on errors up to 0.008). An arc's side face is
    placed no finer than ``ARC_FORM`` of its radius."""
    cloud = seam_cloud(
        2.0,
        0.3,
        ("round", 3.5),
        ("round", 4.0),
        spacing_mm=0.05,
        yaw_deg=2.0,
        length_mm=60.0,
        width_mm=50.0,
    )
    seam = _one_seam(measure(cloud, CONFIG))
    measured = seam.measured
    errors = np.abs(seam.sections_gap_mm[measured] - 2.0)
    assert measured.mean() > 0.95
    assert np.mean(errors <= 2 * seam.sections_gap_sigma_mm[measured]) >= 0.95
    assert np.median(seam.sections_gap_sigma_mm[measured]) < 0.02


def test_a_tapered_seam_along_the_rows_claims_the_lattice_it_shares() -> None:
    """Square corners 0.1 mm apart in the scan, rows along a seam whose gap widens from
    2.3 to 2.7 mm: both edges cross the lattice's points together, and the gap's error
    runs evenly from −s to +s along the seam (σ s/√3) — in quadrature the sides' σ gave
    s/√6, and a fifth of the sections lay beyond 2σ."""
    cloud = seam_cloud(
        2.3, 0.3, ("square", 0), ("square", 0), spacing_mm=0.1, yaw_deg=0.0, taper_mm=0.4
    )
    seam = _one_seam(measure(cloud, CONFIG))
    truth = 2.3 + 0.4 * (seam.sections_at[:, 1] - cloud.points[:, 1].min()) / 100.0
    errors = seam.sections_gap_mm[seam.measured] - truth[seam.measured]
    assert seam.measured.mean() > 0.9
    assert np.abs(errors).max() > 0.09  # the lattice's error, as it is
    assert np.mean(np.abs(errors) <= 2 * seam.sections_gap_sigma_mm[seam.measured]) >= 0.95


def test_a_wide_arc_seen_at_few_places_is_placed_by_its_radius(tmp_path) -> None:
    """The seed-3 assembly at 0.75 mm (``vista defects simulate --seed 3``): arcs of about
    1.6 mm, one or two of the coarse grid's columns on them in most sections. Their
    radius, shared along each seam, pins the edge where no chamfer explains the points as
    well; the floor a few columns gave (the stretch / √3) made every parallelism's σ
    0.65–1.2 mm on errors of 0.02 — each judged "too close for a scan to decide"."""
    from services.defects.example import write_defects_example
    from services.defects.simulate import AssemblySpec
    from services.lib.pointcloud.ply import read_ply

    write_defects_example(tmp_path, AssemblySpec(), grid=(133, 205), seed=3)
    result = measure(read_ply(tmp_path / "cloud.ply"), CONFIG)
    sigmas = [f.sigma_mm for f in result.findings if f.type == "parallelism"]
    assert len(sigmas) == 4 and max(sigmas) < 0.25, sigmas


def test_a_gap_wider_than_the_shadow_and_the_corners_placing_is_measured() -> None:
    """A 0.8 mm gap beside a 0.8 mm step, at 0.5 mm spacing: a view 30° off the normal
    would hide 0.46 mm beyond the higher panel's wall, and the corners are placed to about
    a tenth of a millimetre from the pooled profiles — so the lower corner is seen. (The
    shadow rule's margin was a whole spacing: every section was left unmeasured.)"""
    seam = _one_seam(
        _measured(0.8, 0.8, ("square", 0), ("square", 0), spacing_mm=0.5, yaw_deg=15.0)
    )
    assert seam.measured.mean() >= 0.9, seam.sections_unmeasured
    assert np.percentile(np.abs(seam.sections_gap_mm[seam.measured] - 0.8), 95) < 0.1


def test_rows_along_the_seam_advise_turning_the_scan() -> None:
    """Profiles that all sample the edges at one place leave stretches of a spacing near
    the tops' ends however many are pooled: the gap's advice, when it is uncertain, says
    to turn the scan lines to the seam as well as to scan finer."""
    along = _measured(2.3, 0.4, ("square", 0), ("square", 0), spacing_mm=1.0, yaw_deg=0.0)
    assert _one_seam(along).edge_sampling_mm >= 0.9 * along.spacing_mm
    assert next(f for f in along.findings if f.type == "gap").measurements.one_phase
    turned = _measured(2.3, 0.4, ("square", 0), ("square", 0), spacing_mm=1.0, yaw_deg=15.0)
    assert _one_seam(turned).edge_sampling_mm < 0.5 * turned.spacing_mm
    assert next(f for f in turned.findings if f.type == "gap").measurements.one_phase is None
    words = advice(2.3, 2.0, 0.4, 1.0, one_phase=True)
    assert "re-scan at ≤ 0.37 mm spacing" in words and "turned 5–15° to the seam" in words
    assert "turned" not in advice(2.3, 2.0, 0.4, 1.0)


@pytest.mark.parametrize(("yaw", "widened"), [(0.0, False), (2.0, True)])
def test_slabs_are_thickened_only_where_the_phase_drifts(monkeypatch, yaw, widened) -> None:
    """Rows 2° off the seam drift in phase along it: the middle half of a slab samples
    the edges more coarsely than the whole, so a thicker slab gains, and the seam's
    sections are all profiled from thicker slabs — their probe alone at the usual width.
    Rows exactly along it sample the edges at one phase whatever the slab's thickness: no
    thicker slab is taken (it cost a 0.1 mm cloud a third of its time, then thrown away)."""
    calls = []
    profiled = measure_module.profile_seam

    def counted(slab, seam, config, first, count, spacing_mm):
        calls.append((count, float(np.abs(slab[1]).max())))  # sections, half thickness
        return profiled(slab, seam, config, first, count, spacing_mm)

    monkeypatch.setattr(measure_module, "profile_seam", counted)
    seam = _one_seam(
        measure(
            seam_cloud(2.3, 0.4, ("square", 0), ("square", 0), spacing_mm=1.0, yaw_deg=yaw),
            CONFIG,
        )
    )
    assert seam.measured.mean() >= 0.9
    (probe, probe_half), (count, half) = calls
    assert measure_module.PROBE_SECTIONS <= probe < count
    assert probe_half <= 5.0  # ten spacings: the usual slab
    assert (half > 10.0) == widened, calls


def test_a_seam_is_followed_where_a_view_saw_the_backing_under_a_panels_edge() -> None:
    """A second view looked through the gap at an angle and saw the backing under panel
    a's edge (open behind the panels): over 60 mm of the seam, the backing's points lie
    among the top's within 4 mm of its edge, and those cells are no top on the height map.
    The seam was cut where they were (a 2 × 2 assembly at 15° to the scan lost a third of
    its long seams); it is now followed along its whole length, and measured there."""
    cloud = seam_cloud(3.0, 0.4, ("square", 0), ("square", 0), spacing_mm=0.2)
    rng = np.random.default_rng(5)
    y = rng.uniform(50.0, 90.0, 5_000)  # as dense as the top: 25 points per mm²
    x = -1.5 - rng.uniform(0.0, 5.0, y.shape)  # under panel a's top, beside the gap
    backing = np.stack([x, y, rng.normal(-15.0, 0.02, y.shape)], 1).astype(np.float32)
    result = measure(PointCloud(points=np.concatenate([cloud.points, backing])), CONFIG)
    seam = _one_seam(result)
    assert seam.length_mm > 90
    assert seam.measured.mean() > 0.9, seam.sections_unmeasured
    assert np.percentile(np.abs(seam.sections_gap_mm[seam.measured] - 3.0), 95) < 0.05


def test_seams_beside_panels_merged_across_a_corner_are_found() -> None:
    """A 2 × 2 assembly whose top-left panel touches its two neighbours (no gap: the
    three read as one L-shaped top, as a coarse scan across narrow gaps merges them): the
    fourth panel's boundary with it is bent, and was fitted as one diagonal line that
    no top ran beside — no seam found. Split at the bend, it is two seams, each measured."""
    rng = np.random.default_rng(4)
    x, y = np.meshgrid(np.arange(-100, 100, 0.25), np.arange(-60, 60, 0.25), indexing="ij")
    x, y = x.ravel() + 0.03, y.ravel() + 0.03
    in_gap = ((np.abs(x) < 1.5) & (y < 0)) | ((np.abs(y) < 1.5) & (x > 0))
    z = np.where(in_gap, -15.0, 0.0) + rng.normal(0, 0.02, x.shape)
    cloud = PointCloud(points=np.stack([x, y, z], 1).astype(np.float32))
    result = measure(cloud, CONFIG)
    assert len(result.panels) == 2 and len(result.seams) == 2
    for seam in result.seams:
        assert seam.length_mm > 40
        assert seam.measured.mean() > 0.9, seam.sections_unmeasured
        assert abs(seam.gap_mm.mean - 3.0) < 0.05


@pytest.mark.parametrize(
    ("gap", "step", "spacing", "yaw"),
    [(0.0, 0.5, 0.75, 2.0), (0.0, 0.3, 1.0, 15.0), (0.02, 0.4, 0.5, 15.0)],
)
def test_panels_at_a_step_are_told_apart_where_no_gap_is_seen(gap, step, spacing, yaw) -> None:
    """Panels that touch (or all but: no scan row falls in the gap) at a coarse spacing
    read as one flat top — a step smaller than a cell is no steep slope — and the seam
    was not found at all. The step parts them (``panels._steps``): the seam is found,
    its step measured, and its gap left unmeasured with the reason."""
    cloud = seam_cloud(gap, step, ("square", 0), ("square", 0), spacing_mm=spacing, yaw_deg=yaw)
    result = measure(cloud, CONFIG)
    assert len(result.panels) == 2
    seam = _one_seam(result)
    steps = seam.sections_step_mm[np.isfinite(seam.sections_step_mm)]
    assert len(steps) >= 0.9 * len(seam.sections_step_mm)
    assert np.percentile(np.abs(np.abs(steps) - step), 95) < 0.05
    assert not seam.measured.any() and all(seam.sections_unmeasured)


def test_gap_modes_follow_the_trade_definitions() -> None:
    """walls (default) and surface: along the tops; distance and sharp: straight from edge
    point to edge point (here with a 0.8 mm step between the corners)."""
    cloud = seam_cloud(2.0, 0.8, ("square", 0), ("square", 0))
    expected = {
        "walls": 2.0,
        "surface": 2.0,
        "distance": np.hypot(2.0, 0.8),
        "sharp": np.hypot(2.0, 0.8),
    }
    for mode, value in expected.items():
        config = replace(CONFIG, sections=replace(CONFIG.sections, gap_mode=mode))
        seam = _one_seam(measure(cloud, config))
        assert abs(np.median(seam.sections_gap_mm[seam.measured]) - value) < 0.02, mode
    # rounded edges: the edge points are where each arc meets its side face, 1 mm down
    cloud = seam_cloud(2.0, 0.3, ("round", 1.0), ("round", 1.0))
    config = replace(CONFIG, sections=replace(CONFIG.sections, gap_mode="distance"))
    seam = _one_seam(measure(cloud, config))
    assert abs(np.median(seam.sections_gap_mm[seam.measured]) - np.hypot(2.0, 0.3)) < 0.03


def test_an_edge_no_model_describes_is_not_measured() -> None:
    seam = _one_seam(_measured(2.0, 0.0, ("rebate", 1.0), ("square", 0)))
    reasons = [r for r in seam.sections_unmeasured if r]
    assert seam.measured.mean() < 0.2
    assert any("panel a's edge fits no model" in r for r in reasons), reasons[:3]
    assert seam.unmeasured is not None and seam.gap_mm is None and seam.parallelism_mm is None


def test_a_gap_narrower_than_two_spacings_between_corners_is_not_measured() -> None:
    seam = _one_seam(_measured(0.12, 0.0, ("square", 0), ("square", 0)))
    reasons = [r for r in seam.sections_unmeasured if r]
    assert seam.measured.mean() < 0.1
    assert any("under twice what the profiles resolve" in r or "no gap seen" in r for r in reasons)
    # … while between arcs, whose shape places their side faces, it is measured
    seam = _one_seam(_measured(0.12, 0.0, ("round", 1.0), ("round", 1.0)))
    assert seam.measured.mean() > 0.9
    assert np.percentile(np.abs(seam.sections_gap_mm[seam.measured] - 0.12), 95) < 0.05


def _shadowed() -> PointCloud:
    """A 0.5 mm gap beside a 1.5 mm step whose lower corner no ray is seen to have reached:
    nothing returned from the gap beside it (as where a view's rays were blocked)."""
    cloud = seam_cloud(0.5, 1.5, ("square", 0), ("square", 0))
    x, z = cloud.points[:, 0], cloud.points[:, 2]
    return PointCloud(points=cloud.points[~((z < -5) & (x < 0.1))])


def test_a_corner_that_may_be_in_a_steps_shadow_is_measured_only_where_seen() -> None:
    """A square corner on the lower panel closer to the higher one than step × tan 30° may
    be hidden from an oblique view: the cloud does not say where it was seen from. Where
    nothing below the corner beside it returned (no ray reached into the gap there),
    vista does not trust it; where the backing was seen through the gap beside it, a view
    passed the higher panel's edge to the corner — it is measured (it was refused whatever
    was seen: a 0.1 mm scan at 2° to its seams lost 16 % of its sections so)."""
    result = measure(_shadowed(), CONFIG)
    seam = _one_seam(result)
    assert not seam.measured.any()
    assert "panel a's edge may lie in panel b's shadow" in seam.sections_unmeasured[0]
    assert seam.unmeasured.startswith("only 0 of")
    # no gap or parallelism finding; the step (the tops are seen) still is one
    kinds = {f.type for f in result.findings}
    assert kinds == {"step"}
    assert np.isfinite(seam.sections_step_mm).all()
    seen = _one_seam(_measured(0.5, 1.5, ("square", 0), ("square", 0)))
    assert seen.measured.all()
    errors = seen.sections_gap_mm - 0.5
    assert np.percentile(np.abs(errors), 95) < 0.03
    assert np.mean(np.abs(errors) <= 2 * seen.sections_gap_sigma_mm) >= 0.9


def test_a_hole_at_the_edge_is_not_taken_for_the_edge() -> None:
    cloud = seam_cloud(2.0, 0.0, ("square", 0), ("square", 0))
    x, y = cloud.points[:, 0], cloud.points[:, 1]
    hole = (x > 1.3) & (x < 1.8) & (y > 40) & (y < 60)  # 0.3–0.8 mm inside b's edge
    seam = _one_seam(measure(PointCloud(points=cloud.points[~hole]), CONFIG))
    at_hole = (seam.sections_at[:, 1] > 41) & (seam.sections_at[:, 1] < 59)
    assert not seam.measured[at_hole].any()
    assert "panel b's top continues past a hole" in seam.sections_unmeasured[np.argmax(at_hole)]
    assert seam.measured[~at_hole].mean() > 0.9


def test_panels_can_be_located_and_the_step_sign_follows_the_rule() -> None:
    """b is the panel on the + side of the cloud axis the seam's across direction is
    closest to; the step is b's top over a's. Mirrored, the same rule holds."""
    cloud = seam_cloud(2.0, 0.8, ("square", 0), ("square", 0), yaw_deg=0.0)
    for mirror in (1.0, -1.0):
        points = cloud.points * np.array([mirror, 1.0, 1.0], np.float32)
        result = measure(PointCloud(points=points), CONFIG)
        seam = _one_seam(result)
        a, b = (result.panels[i] for i in seam.panels)
        assert b.centroid[0] > a.centroid[0]
        expected = b.centroid[2] - a.centroid[2]  # ±0.8: the +x panel's top over the other's
        assert abs(expected - 0.8 * mirror) < 0.02
        assert abs(np.median(seam.sections_step_mm) - expected) < 0.02
    # panel ids follow the centroids (x first), and each panel is where it says
    assert [p.id for p in result.panels] == [0, 1]
    assert result.panels[0].centroid[0] < result.panels[1].centroid[0]
    for panel in result.panels:
        assert np.allclose(panel.normal, [0, 0, 1], atol=0.01)
        assert (panel.bounds_min <= panel.centroid).all() and (
            panel.centroid <= panel.bounds_max
        ).all()
        assert 4 <= len(panel.outline) <= 12  # a rectangle, simplified
        assert panel.bounds_max[1] - panel.bounds_min[1] > 95
        assert abs(panel.area_mm2 - 100 * 29) < 200
    # turned 90°: the seam runs along x, and b is the panel at +y
    turned = PointCloud(points=cloud.points[:, [1, 0, 2]] * np.array([1, -1, 1], np.float32))
    result = measure(turned, CONFIG)
    seam = _one_seam(result)
    a, b = (result.panels[i] for i in seam.panels)
    assert b.centroid[1] > a.centroid[1]
    assert np.sign(np.median(seam.sections_step_mm)) == np.sign(b.centroid[2] - a.centroid[2])


def test_result_and_cli_report_unmeasured_sections(tmp_path) -> None:
    result = measure(_shadowed(), CONFIG)
    document = result_document(result, CONFIG)
    json.dumps(document, allow_nan=False)
    seam = document["seams"][0]
    assert seam["unmeasured"] and seam["gap_mm"] is None and seam["sections_measured"] == 0
    section = seam["sections"][0]
    assert section["gap_mm"] is None and "shadow" in section["unmeasured"]
    assert section["edges"] == ["square", "square"] and section["step_mm"] is not None
    panel = document["panels"][0]
    assert {"id", "centroid", "bounds_mm", "normal", "area_mm2", "outline"} <= set(panel)
    assert set(panel["bounds_mm"]) == {"min", "max"} and len(panel["outline"][0]) == 3
    assert "step" in document["rules"] and "seam panels" in document["rules"]
    path = tmp_path / "cloud.ply"
    write_ply(path, _shadowed())
    out = tmp_path / "result.json"
    done = CliRunner().invoke(app, ["defects", "measure", str(path), "-o", str(out)])
    assert done.exit_code == 0, done.output
    assert "UNMEASURED — only 0 of" in done.output and "panel 0: centre" in done.output
    assert "WARNING: 1 of 1 seam unmeasured: their gap, parallelism and mismatch" in done.output
    assert document["unmeasured_seams"] == [
        {"seam": 0, "panels": seam["panels"], "why": seam["unmeasured"]}
    ]


def test_measurement_settings_name_their_choices() -> None:
    config = parse_config({"measurement": {"edge_model": "square", "gap_mode": "distance"}})
    assert config.sections.edge_model == "square" and config.sections.gap_mode == "distance"
    with pytest.raises(ConfigError, match=r"measurement.edge_model: Input should be 'auto'"):
        parse_config({"measurement": {"edge_model": "bevel"}})
    with pytest.raises(ConfigError, match=r"measurement.gap_mode: Input should be 'walls'"):
        parse_config({"measurement": {"gap_mode": 3}})
    # a user's choice of model is used on every side
    cloud = seam_cloud(2.0, 0.3, ("round", 1.0), ("round", 1.0))
    forced = replace(CONFIG, sections=replace(CONFIG.sections, edge_model="round"))
    seam = _one_seam(measure(cloud, forced))
    assert [e.model for e in seam.edges] == ["round", "round"]


def test_a_fallback_edge_far_off_its_seams_line_is_left_unmeasured() -> None:
    """The spacing sweep's square edges at 0.1 mm, rows along the seams: where a seam met
    a junction, the free fallback took the crossing seam's edge in seven sections, gaps
    1.5–2.3 mm too wide with σ 0.076 (30σ). A fallback section that departs from the line
    of the seam's modelled sections by more than ``DEPARTURE_SIGMAS`` is unmeasured; one
    within it, and any modelled section, is kept."""
    from services.defects.edges import FREE, SQUARE
    from services.defects.sections import _departing

    along = np.arange(12.0) * 2
    gap = 1.2 - 0.01 * along + np.tile([0.0, 0.02, -0.02], 4)  # a tapered seam's gaps
    models = np.full((12, 2), SQUARE)
    models[[9, 10], 1] = FREE
    gap[9] += 0.05  # a fallback within the spread
    gap[10] += 1.5  # a fallback on another edge
    gap[11] += 1.5  # a modelled section: kept, whatever its gap
    sigma = np.full(12, 0.02)
    assert _departing(gap, sigma, along, models).tolist() == [False] * 10 + [True, False]
    few = models.copy()
    few[2:, 0] = FREE  # fewer than three modelled sections: no line to depart from
    assert not _departing(gap, sigma, along, few).any()
