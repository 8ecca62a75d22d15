"""``vista defects bench``: accuracy against ground truth over a sweep of assemblies (gap,
step, taper, noise, curvature, density), detection precision/recall per defect type, and
time per square metre — with a single-profile gap gauge as the peer, in the same run —
and an edge sweep: square, chamfered and rounded edges (0.2–5 mm), mixed sides, views
tilted 15° and 30°, dropout, burrs, gaps narrower than two point spacings, mixed pixels and
spikes, dark and shiny patches, misregistered scans, and corners hidden in a step's
shadow, each with the gauge on the same clouds and the share of sections left
unmeasured.

Each run simulates a 2 × 2 (or 2 × 3) assembly of 150 × 100 mm panels, scans it with the
stitching simulator's sensor (σ along the ray, occlusion, incidence drop-out, strays) at
the case's spacing, merges the scans at their true poses (so only the measurement is
judged, not the stitch) and measures it. The peer measures the same seams the way a
profile gauge does: one scan line per section (a slab of twice the point spacing instead
of 1 mm) and the gap between the last measured points of each panel (no model of the
rounded edge). It is modelled on profile-based gap/flush tools, not any vendor's firmware.

Time per m² is that of a whole measurement (frame to findings; the cloud in memory), the
median of ``TIMED_RUNS`` runs on each assembly, over the cases' panel area — vista's and the
gauge's, their runs alternated so that other work on the machine weighs on both alike —
against ``SECONDS_PER_M2`` (issue 35) in every case of both sweeps.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from contract.bench import print_verdict, say, write_document
from services.defects.bench_nominal import DISTANCE_POINTS, run_nominal_sweep
from services.defects.bench_nominal import TARGETS as NOMINAL_TARGETS
from services.defects.config import MeasureConfig
from services.defects.evaluate import Evaluation, error_p95, evaluate, within_2sigma
from services.defects.example import BASE_T_PART, merged_cloud
from services.defects.measure import MeasureResult, measure, warm_up
from services.defects.simulate import (
    AssemblyScanner,
    AssemblySpec,
    random_assembly,
    scan_assembly,
)
from services.defects.truth import truth_of
from services.lib.pointcloud.ply import PointCloud
from services.lib.pointcloud.scan_sim import SensorModel
from services.lib.pointcloud.transforms import from_rotvec
from services.lib.process import available_cores, prepare_process

SECONDS_PER_M2 = 2.5
"""Issue 35's target: no case of either sweep slower than this per m² of panel at 0.1 mm
spacing."""
TARGETS = {
    "gap and step error p95 (mm)": 0.05,
    "edge sweep: gap and step error p95 (mm)": 0.05,
    "edge sweep: largest gap error of a measured section (mm)": 0.2,
    "edge sweep: negative gaps": 0,
    "edge sweep: unmeasurable sections left unmeasured": 0.99,
    "parallelism and mismatch error max (mm)": 0.05,
    "geometric precision and recall": 0.98,
    "surface recall": 0.95,
    "surface false positives per m²": 1.0,
    "seconds per m²": SECONDS_PER_M2,
    "edge sweep: seconds per m²": SECONDS_PER_M2,
}


TIMED_RUNS = 7
"""Each assembly is measured this many times, by vista and by the gauge, and the median time
kept (a measuring worker in its steady state): single timings of the ~0.3 s measurement on a
shared 2-core machine spread by up to +70 %."""


@dataclass(frozen=True)
class SweepCase:
    name: str
    spec: AssemblySpec = field(default_factory=AssemblySpec)
    spacing_mm: float = 0.1
    noise_mm: float = 0.02
    tilt_deg: float = 0.0
    """Views turned about the base x axis (``scan_assembly``)."""
    mixed_pixel_fraction: float = 0.0
    edge_spike_fraction: float = 0.0
    max_incidence_deg: float = 75.0
    misregistration_mm: float = 0.0
    yaw_deg: float = 0.0
    """The assembly turned about the base z axis: its seams cross the sensor's pixel rows
    at this angle instead of running exactly along them."""
    field_mm: tuple[float, float] = (154.0, 100.0)
    """The sensor's field (width, height) at its standoff; a narrow one sees every point
    from nearly the same angle (a line scanner)."""
    edge: str = ""
    """The spacing sweep's edge kind (``square``, ``chamfer``, ``round``)."""


CASES = (
    SweepCase("nominal"),
    SweepCase("small gaps 0.3–1 mm", AssemblySpec(gap_mm=(0.3, 1.0))),
    SweepCase("near-flush ±0.3 mm steps", AssemblySpec(step_mm=(-0.3, 0.3))),
    SweepCase("taper 1–2 mm", AssemblySpec(taper_mm=(1.0, 2.0))),
    SweepCase("sharp edges r 0.5 mm", AssemblySpec(edge_radius_mm=(0.5, 0.6))),
    SweepCase("noise σ 0.04 mm", noise_mm=0.04),
    SweepCase("curved R 1500 mm", AssemblySpec(radius_mm=1500.0)),
    SweepCase("curved R 3000 mm, 2 × 3", AssemblySpec(cols=3, radius_mm=3000.0)),
    SweepCase("spacing 0.2 mm", spacing_mm=0.2),
)

_EDGES = dict(gap_mm=(0.3, 5.0), step_mm=(-2.0, 2.0))
_ALL_KINDS = dict(edge_kinds=("square", "chamfer", "round"), edge_radius_mm=(0.2, 5.0), **_EDGES)
SEAM_YAW_DEG = 5.0
"""In the edge sweep the assembly lies turned by this about the vertical, so the sensor's
pixel rows cross the seams (as they do unless a robot is taught to follow each seam to a
fraction of a degree). Where they run exactly along a seam, every row samples a square
corner at the same phase and no method can place it closer than the spacing: the sweep's
"rows along the seams" case shows that limit."""


def _edge_case(name: str, spec: AssemblySpec, **kw: object) -> SweepCase:
    return SweepCase(name, spec, yaw_deg=kw.pop("yaw_deg", SEAM_YAW_DEG), **kw)


EDGE_CASES = (
    _edge_case("square", AssemblySpec(edge_kinds=("square",), **_EDGES)),
    _edge_case(
        "square, rows along the seams (limit)",
        AssemblySpec(edge_kinds=("square",), **_EDGES),
        yaw_deg=0.0,
    ),
    _edge_case(
        "chamfer 0.3 mm", AssemblySpec(edge_kinds=("chamfer",), chamfer_mm=(0.3, 0.3), **_EDGES)
    ),
    _edge_case(
        "chamfer 1 mm", AssemblySpec(edge_kinds=("chamfer",), chamfer_mm=(1.0, 1.0), **_EDGES)
    ),
    _edge_case("round 0.2 mm", AssemblySpec(edge_radius_mm=(0.2, 0.2), **_EDGES)),
    _edge_case("round 0.2–5 mm", AssemblySpec(edge_radius_mm=(0.2, 5.0), **_EDGES)),
    _edge_case("round 5 mm", AssemblySpec(edge_radius_mm=(5.0, 5.0), **_EDGES)),
    _edge_case("mixed sides", AssemblySpec(**_ALL_KINDS)),
    _edge_case("tilted 15°", AssemblySpec(**_ALL_KINDS), tilt_deg=15.0),
    _edge_case("tilted 30°", AssemblySpec(**_ALL_KINDS), tilt_deg=30.0),
    _edge_case("dropout: incidence ≤ 60°", AssemblySpec(**_ALL_KINDS), max_incidence_deg=60.0),
    _edge_case(
        "burr 0.05–0.2 mm (square edges)",
        AssemblySpec(edge_kinds=("square",), burr_mm=(0.05, 0.2), **_EDGES),
    ),
    _edge_case(
        "narrow gaps 0.05–0.2 mm",
        AssemblySpec(**{**_ALL_KINDS, "gap_mm": (0.05, 0.2), "taper_mm": (0.0, 0.05)}),
    ),
    _edge_case(
        "mixed pixels and spikes",
        AssemblySpec(**_ALL_KINDS),
        mixed_pixel_fraction=0.3,
        edge_spike_fraction=0.05,
    ),
    _edge_case("dark and shiny patches", AssemblySpec(dark_patches=3, **_ALL_KINDS)),
    _edge_case("scans misregistered 0.05 mm", AssemblySpec(**_ALL_KINDS), misregistration_mm=0.05),
    _edge_case(
        "shadowed corners (unmeasurable)",
        AssemblySpec(
            edge_kinds=("square",), gap_mm=(0.2, 0.6), step_mm=(-3.0, 3.0), taper_mm=(0.0, 0.2)
        ),
        tilt_deg=30.0,
        field_mm=(154.0, 40.0),
    ),
)
SPACINGS_MM = (0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0)
GRID_ANGLES_DEG = (0.0, 2.0, 15.0, 45.0)
SPACING_NOISE_MM = (0.02, 0.05)
SPACING_TARGETS = ((0.2, 0.98, 0.05), (0.5, 0.95, 0.10), (1.0, 0.90, 0.20))
"""Issue 54, per band of spacings (up to the first number, mm): the share of sections
measured, and the gap and step error p95 (mm); and in every band, ≥ 90 % of measured
sections' and of seams' gaps within 2σ of the truth."""
COVERAGE_TARGET = 0.9
SPACING_TIMED_RUNS = 3
"""The spacing sweep has 168 cells: each assembly is timed over fewer runs."""


def spacing_cases(
    spacings: tuple[float, ...] = SPACINGS_MM,
    angles: tuple[float, ...] = GRID_ANGLES_DEG,
    noises: tuple[float, ...] = SPACING_NOISE_MM,
    edges: tuple[str, ...] = ("square", "chamfer", "round"),
) -> tuple[SweepCase, ...]:
    """The spacing sweep: every ``edges`` kind of the edge sweep (round 0.2–5 mm, chamfer
    0.3–1 mm) at every spacing, with the scan grid at every angle to the seams (the
    assembly turned about the vertical: the seams along x cross the pixel rows at that
    angle, those along y at 90° less) and every noise σ."""
    specs = {
        "square": AssemblySpec(edge_kinds=("square",), **_EDGES),
        "chamfer": AssemblySpec(edge_kinds=("chamfer",), **_EDGES),
        "round": AssemblySpec(edge_radius_mm=(0.2, 5.0), **_EDGES),
    }
    return tuple(
        SweepCase(
            f"{edge} {spacing:g} mm, grid {angle:g}°, σ {noise:g}",
            specs[edge],
            spacing_mm=spacing,
            noise_mm=noise,
            yaw_deg=angle,
            edge=edge,
        )
        for spacing in spacings
        for edge in edges
        for angle in angles
        for noise in noises
    )


LIMIT_CASES = ("square, rows along the seams (limit)",)
"""Shown for what they teach, not held to the accuracy targets."""
SWEEPS = {
    "assemblies": CASES,
    "edges": EDGE_CASES,
    "spacing": spacing_cases(),
    "nominal": (),  # parts against their nominal: services.defects.bench_nominal
}


def _run(
    case: SweepCase, seed: int, threads: int, timed_runs: int = TIMED_RUNS
) -> tuple[Evaluation, Evaluation]:
    """(vista, gauge) evaluations of one simulated assembly, measured on ``threads``, each
    timed as the median of ``timed_runs``."""
    rng = np.random.default_rng(seed)
    assembly = random_assembly(case.spec, rng)
    width, height = case.field_mm
    sensor = SensorModel(
        grid=(int(round(height / case.spacing_mm)), int(round(width / case.spacing_mm))),
        field_mm=case.field_mm,
        noise_mm=case.noise_mm,
        max_incidence_deg=case.max_incidence_deg,
        mixed_pixel_fraction=case.mixed_pixel_fraction,
        edge_spike_fraction=case.edge_spike_fraction,
    )
    base_T_part = BASE_T_PART @ from_rotvec(np.radians([0.0, 0.0, case.yaw_deg]), np.zeros(3))
    scans = scan_assembly(assembly, base_T_part, sensor, tilt_deg=case.tilt_deg, rng=rng)
    cloud = merged_cloud(scans, voxel_mm=0.1, misregistration_mm=case.misregistration_mm)
    truth = truth_of(assembly, base_T_part)
    scanner, seams = AssemblyScanner(assembly, base_T_part, sensor), assembly.seams

    def seen(seam_id: int, fraction: np.ndarray) -> np.ndarray:
        return scanner.edges_seen(scans.base_T_sensor, seams[seam_id], fraction)

    config = MeasureConfig()
    # One scan line: the slab just wide enough to hold a continuous profile of the cloud.
    gauge_sections = replace(
        config.sections, slab_mm=2 * case.spacing_mm, min_profiles=0, edge_model="void"
    )
    gauge_config = replace(config, sections=gauge_sections, surface=None)
    (result, seconds), (gauge_result, gauge_seconds) = _timed(
        cloud, (config, gauge_config), threads, timed_runs
    )
    vista = replace(evaluate(result, truth, config.tolerances, seen=seen), seconds=seconds)
    gauge = replace(
        evaluate(gauge_result, truth, config.tolerances, seen=seen), seconds=gauge_seconds
    )
    return vista, gauge


def _timed(
    cloud: PointCloud, configs: tuple[MeasureConfig, ...], threads: int, runs: int
) -> list[tuple[MeasureResult, float]]:
    """Each config's measurement of ``cloud`` and the median of its ``runs`` times, the
    configs' runs taken in turn."""
    results: list[MeasureResult | None] = [None] * len(configs)
    timings: list[list[float]] = [[] for _ in configs]
    for _ in range(runs):
        for i, config in enumerate(configs):
            results[i] = measure(cloud, config, threads=threads)
            timings[i].append(sum(results[i].seconds.values()))
    return [(r, float(np.median(t))) for r, t in zip(results, timings, strict=True)]


def _rounded(values: list[float] | np.ndarray) -> list[float]:
    """|errors| (mm, or in σ) as the row keeps them, for figures pooled over cells."""
    return np.round(np.asarray(values, float), 4).tolist()


def _row(case: SweepCase, vista: Evaluation, gauge: Evaluation, runs: int) -> dict:
    v, g = vista.summary(), gauge.summary()
    return {
        "case": case.name,
        "runs": runs,
        "spacing_mm": case.spacing_mm,
        "noise_mm": case.noise_mm,
        "grid_angle_deg": case.yaw_deg,
        "edge": case.edge,
        "vista": v,
        "errors": {
            "gap_mm": _rounded(np.abs(vista.gap_errors_mm)),
            "step_mm": _rounded(np.abs(vista.step_errors_mm)),
            "sections_sigma": _rounded(vista.gap_errors_sigma),
            "seam_ends_sigma": _rounded(vista.seam_end_errors_sigma),
        },
        "gauge": {
            k: g[k]
            for k in (
                "gap_error_mean_mm",
                "gap_error_p95_mm",
                "gap_error_max_mm",
                "negative_gaps",
                "unmeasured_share",
                "step_error_p95_mm",
                "parallelism_error_max_mm",
                "mismatch_error_max_mm",
                "geometric",
                "seconds_per_m2",
            )
        },
    }


def _fmt(value: float | None, digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _accuracy_table(rows: list[dict]) -> str:
    lines = [
        "| case | sections | gap err p95 mm (gauge) | gap bias mm (gauge) | step err p95 mm (gauge) "
        f"| parallelism err max mm | mismatch err max mm | s/m² ≤ {SECONDS_PER_M2:g} (gauge) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        v, g = r["vista"], r["gauge"]
        lines.append(
            f"| {r['case']} | {v['sections']} | {_fmt(v['gap_error_p95_mm'])} "
            f"({_fmt(g['gap_error_p95_mm'])}) | {_fmt(v['gap_error_mean_mm'])} "
            f"({_fmt(g['gap_error_mean_mm'])}) | {_fmt(v['step_error_p95_mm'])} "
            f"({_fmt(g['step_error_p95_mm'])}) | {_fmt(v['parallelism_error_max_mm'])} "
            f"| {_fmt(v['mismatch_error_max_mm'])} | {_speed(v, g)} |"
        )
    return "\n".join(lines)


def _detection_table(total: dict, gauge_total: dict) -> str:
    lines = [
        "| type | TP | FP | FN | precision | recall | gauge precision / recall |",
        "|---|---|---|---|---|---|---|",
    ]
    for kind, c in total["geometric"].items():
        gc = gauge_total["geometric"][kind]
        lines.append(
            f"| {kind} | {c['tp']} | {c['fp']} | {c['fn']} | {c['precision']:.3f} | "
            f"{c['recall']:.3f} | {gc['precision']:.3f} / {gc['recall']:.3f} |"
        )
    for kind, c in total["surface"].items():
        lines.append(f"| {kind} | {c['tp']} | {c['fp']} | {c['fn']} | – | {c['recall']:.3f} | – |")
    return "\n".join(lines)


def _verdict(total: dict, rows: list[dict]) -> dict[str, bool]:
    def all_below(key: str, limit: float) -> bool:
        return all(r["vista"][key] is not None and r["vista"][key] <= limit for r in rows)

    geometric = total["geometric"].values()
    surface = total["surface"].values()
    return {
        "gap and step error p95 ≤ 0.05 mm in every case": all_below("gap_error_p95_mm", 0.05)
        and all_below("step_error_p95_mm", 0.05),
        "parallelism and mismatch error ≤ 0.05 mm in every case": all_below(
            "parallelism_error_max_mm", 0.05
        )
        and all(
            r["vista"]["mismatch_error_max_mm"] is None
            or r["vista"]["mismatch_error_max_mm"] <= 0.05
            for r in rows
        ),
        "geometric precision and recall ≥ 0.98": all(
            c["precision"] >= 0.98 and c["recall"] >= 0.98 for c in geometric
        ),
        "surface recall ≥ 0.95": all(c["recall"] >= 0.95 for c in surface),
        "≤ 1 surface false positive per m²": total["surface_false_positives_per_m2"] <= 1.0,
        f"≤ {SECONDS_PER_M2:g} s per m² at 0.1 mm spacing in every case": _fast_enough(rows),
    }


def _dense(rows: list[dict]) -> list[dict]:
    """The rows timed at 0.1 mm spacing, the density the speed target is stated for."""
    return [r for r in rows if r["spacing_mm"] == 0.1]


def _fast_enough(rows: list[dict]) -> bool:
    dense = _dense(rows)
    return bool(dense) and all(r["vista"]["seconds_per_m2"] <= SECONDS_PER_M2 for r in dense)


def _beside(v: dict, g: dict, key: str) -> str:
    """vista's figure, the gauge's in brackets."""
    return f"{_fmt(v[key])} ({_fmt(g[key])})"


def _speed(v: dict, g: dict) -> str:
    """A row's s/m², the gauge's in brackets."""
    return f"{_fmt(v['seconds_per_m2'], 1)} ({_fmt(g['seconds_per_m2'], 1)})"


def _speed_line(name: str, rows: list[dict]) -> str:
    """The slowest case at 0.1 mm spacing against the target, and the gauge's slowest."""
    dense = _dense(rows)
    if not dense:
        return f"{name}: no case at 0.1 mm spacing"
    slowest = max(dense, key=lambda r: r["vista"]["seconds_per_m2"])
    gauge = max(r["gauge"]["seconds_per_m2"] for r in dense)
    return (
        f"{name}: slowest case {slowest['vista']['seconds_per_m2']:.1f} s/m² "
        f"({slowest['case']}), target ≤ {SECONDS_PER_M2:g}; the gauge's slowest {gauge:.1f} s/m²"
    )


def _sweep(
    cases: tuple[SweepCase, ...],
    seeds: int,
    seed: int,
    threads: int,
    timed_runs: int = TIMED_RUNS,
    indices: list[int] | None = None,
) -> tuple[list[dict], Evaluation, Evaluation]:
    """Each case's rows over ``seeds`` assemblies: the k-th of case i is simulated from
    seed + 1000 k + i (i: the case's ``indices``, or its place in ``cases``)."""
    rows = []
    all_vista, all_gauge = Evaluation(), Evaluation()
    for index, case in zip(indices or range(len(cases)), cases, strict=True):
        vista, gauge = Evaluation(), Evaluation()
        for k in range(seeds):
            say(f"{case.name}: assembly {k + 1} of {seeds}")
            v, g = _run(case, seed + 1000 * k + index, threads, timed_runs)
            vista.add(v)
            gauge.add(g)
        all_vista.add(vista)
        all_gauge.add(gauge)
        rows.append(_row(case, vista, gauge, seeds))
        v, g = rows[-1]["vista"], rows[-1]["gauge"]
        say(
            f"  gap p95 {_fmt(v['gap_error_p95_mm'])} mm (max {_fmt(v['gap_error_max_mm'])}), "
            f"unmeasured {_fmt(v['unmeasured_share'], 3)}, {_speed(v, g)} s/m² "
            f"(target ≤ {SECONDS_PER_M2:g}; gauge in brackets)"
        )
    return rows, all_vista, all_gauge


def run_defects_bench(
    out: Path,
    *,
    seeds: int = 2,
    seed: int = 0,
    sweeps: tuple[str, ...] = tuple(SWEEPS),
    cases: tuple[SweepCase, ...] = CASES,
    edge_cases: tuple[SweepCase, ...] = EDGE_CASES,
    spacing_sweep: tuple[SweepCase, ...] = SWEEPS["spacing"],
    nominal_points: int = DISTANCE_POINTS,
) -> dict:
    """Run the ``sweeps`` (``assemblies``: ``cases``; ``edges``: ``edge_cases``;
    ``spacing``: ``spacing_sweep``; ``nominal``: parts against their nominal and the
    distance beside CloudCompare's and Open3D's on ``nominal_points`` points), print the
    tables and the verdict, write the JSON document."""
    prepare_process()
    threads = available_cores()
    warm_up()  # compiling the numba passes is once per installation, not per m²
    parts: dict = {"threads": threads}
    verdict: dict[str, bool] = {}
    if "assemblies" in sweeps:
        rows, all_vista, all_gauge = _sweep(cases, seeds, seed, threads)
        total, gauge_total = all_vista.summary(), all_gauge.summary()
        verdict |= _verdict(total, rows)
        parts |= {"cases": rows, "total": total, "gauge_total": gauge_total}
    if "edges" in sweeps:
        edge_rows, _, _ = _sweep(edge_cases, seeds, seed + 100, threads)
        verdict |= _edge_verdict(edge_rows)
        parts["edge_cases"] = edge_rows
    if "spacing" in sweeps:
        # A cell's assemblies are the same whichever part of the sweep is run.
        whole = {case.name: i for i, case in enumerate(SWEEPS["spacing"])}
        indices = [whole.get(case.name, i) for i, case in enumerate(spacing_sweep)]
        spacing_rows, _, _ = _sweep(
            spacing_sweep, seeds, seed + 200, threads, SPACING_TIMED_RUNS, indices
        )
        verdict |= _spacing_verdict(spacing_rows)
        parts["spacing_cases"] = spacing_rows
    if "nominal" in sweeps:  # prints its own tables as it goes
        nominal = run_nominal_sweep(seeds=seeds, seed=seed + 300, threads=threads,
                                    points=nominal_points)  # fmt: skip
        verdict |= nominal.pop("verdict")
        parts |= nominal
    targets = TARGETS | (NOMINAL_TARGETS if "nominal" in sweeps else {})
    document = write_document(out, bench="defects", targets=targets, verdict=verdict, **parts)
    if "assemblies" in sweeps:
        print(
            f"\n## Accuracy against ground truth ({seeds} assemblies per case; peer in brackets)\n"
        )
        print(_accuracy_table(parts["cases"]))
        print(
            "\n## Detection over all cases (default tolerances; surface: detection at the floors)\n"
        )
        print(_detection_table(parts["total"], parts["gauge_total"]))
        print(
            f"\nsurface false positives: {parts['total']['surface_false_positives_per_m2']:.2f} "
            f"per m² of panel ({parts['total']['panel_area_m2']:.3f} m² measured)"
        )
    if "edges" in sweeps:
        print(f"\n## Edge sweep ({seeds} assemblies per case; peer in brackets)\n")
        print(_edge_table(parts["edge_cases"]))
    if "spacing" in sweeps:
        print(f"\n## Spacing sweep ({seeds} assemblies per cell; peer in brackets)\n")
        print(_spacing_table(parts["spacing_cases"]))
        print("\n## Spacing sweep by spacing (all edges, grid angles and noise)\n")
        print(_spacing_summary(parts["spacing_cases"]))
        print(
            "\n## The same by the scan grid's angle to the seams (sections measured / gap "
            "err p95 mm / sections within 2σ)\n"
        )
        print(_angle_table(parts["spacing_cases"]))
        print(
            "\n## The same without the cells that sample a corner at one phase (square and "
            "chamfered edges, grid at 0° or 45°: a gap's error there runs up to a spacing "
            "whatever is pooled; their σ says so)\n"
        )
        print(_spacing_summary([r for r in parts["spacing_cases"] if not _one_phase(r)]))
    print(
        f"\n## Speed ({threads} threads; median of {TIMED_RUNS} runs per assembly, "
        f"{SPACING_TIMED_RUNS} in the spacing sweep)\n"
    )
    for name, key in (
        ("assemblies", "cases"),
        ("edge sweep", "edge_cases"),
        ("spacing sweep", "spacing_cases"),
    ):
        if key in parts:
            print(f"- {_speed_line(name, parts[key])}")
    print_verdict(verdict, out)
    return document


def _edge_table(rows: list[dict]) -> str:
    lines = [
        "| case | sections | unmeasured | gap err p95 mm (gauge) | gap err max mm (gauge) "
        "| step err p95 mm (gauge) | negative gaps (gauge) | unmeasurable left unmeasured "
        f"| edge models | s/m² ≤ {SECONDS_PER_M2:g} (gauge) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        v, g = r["vista"], r["gauge"]
        hidden = v["unmeasurable_sections"]
        flagged = f"{_fmt(v['unmeasurable_flagged_share'], 3)} of {hidden}" if hidden else "–"
        models = ", ".join(f"{k} {n}" for k, n in sorted(v["edge_models"].items()))
        lines.append(
            f"| {r['case']} | {v['sections_total']} | {_fmt(v['unmeasured_share'], 3)} "
            f"| {_beside(v, g, 'gap_error_p95_mm')} | {_beside(v, g, 'gap_error_max_mm')} "
            f"| {_beside(v, g, 'step_error_p95_mm')} "
            f"| {v['negative_gaps']} ({g['negative_gaps']}) | {flagged} | {models} "
            f"| {_speed(v, g)} |"
        )
    return "\n".join(lines)


def _edge_verdict(rows: list[dict]) -> dict[str, bool]:
    def within(key: str, limit: float) -> bool:
        return all(
            r["vista"][key] is None or r["vista"][key] <= limit
            for r in rows
            if r["case"] not in LIMIT_CASES
        )

    hidden = sum(r["vista"]["unmeasurable_sections"] for r in rows)
    flagged = sum(
        round(r["vista"]["unmeasurable_flagged_share"] * r["vista"]["unmeasurable_sections"])
        for r in rows
        if r["vista"]["unmeasurable_sections"]
    )
    return {
        "edge sweep: gap and step error p95 ≤ 0.05 mm in every case": within(
            "gap_error_p95_mm", 0.05
        )
        and within("step_error_p95_mm", 0.05),
        "edge sweep: no measured gap off by more than 0.2 mm": within("gap_error_max_mm", 0.2),
        "edge sweep: no negative gap": all(r["vista"]["negative_gaps"] == 0 for r in rows),
        "edge sweep: ≥ 99 % of unmeasurable sections left unmeasured": hidden == 0
        or flagged >= 0.99 * hidden,
        f"edge sweep: ≤ {SECONDS_PER_M2:g} s per m² at 0.1 mm spacing in every case": (
            _fast_enough(rows)
        ),
    }


def _spacing_table(rows: list[dict]) -> str:
    """One line per cell of the spacing sweep."""
    lines = [
        "| cell | sections measured (gauge) | gap err p95 mm (gauge) | step err p95 mm (gauge) "
        "| sections within 2σ | seam ends within 2σ | s/m² (gauge) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        v, g = r["vista"], r["gauge"]
        lines.append(
            f"| {r['case']} | {_measured(v)} ({_measured(g)}) "
            f"| {_beside(v, g, 'gap_error_p95_mm')} | {_beside(v, g, 'step_error_p95_mm')} "
            f"| {_fmt(v['sections_within_2sigma'], 2)} | {_fmt(v['seam_ends_within_2sigma'], 2)} "
            f"| {_speed(v, g)} |"
        )
    return "\n".join(lines)


def _measured(summary: dict) -> str:
    """The share of sections measured (–: none to measure)."""
    share = summary["unmeasured_share"]
    return "–" if share is None else f"{1 - share:.3f}"


def _spacing_groups(rows: list[dict]) -> dict[float, dict]:
    """Per spacing, over its cells: sections measured and in all; every measured section's
    |gap error| and |step error| and its |error| in σ, every seam end's in σ (pooled, as
    the issue's targets are per spacing); the cells' worst gap and step error p95 and 2σ
    coverage; the slowest s/m²; the gauge's worst gap error p95 and its slowest s/m²."""
    groups: dict[float, dict] = {}
    for r in rows:
        v, g, errors = r["vista"], r["gauge"], r["errors"]
        group = groups.setdefault(
            r["spacing_mm"],
            {"measured": 0, "total": 0, "cells": 0}
            | {key: [] for key in (*errors, *SPACING_WORST, "gauge_gap", "gauge_seconds")},
        )
        group["cells"] += 1
        group["total"] += v["sections_total"]
        group["measured"] += v["sections"]
        for key, values in errors.items():
            group[key] += values
        for key, value in (
            *((key, v[name]) for key, name in SPACING_WORST.items()),
            ("gauge_gap", g["gap_error_p95_mm"]),
            ("gauge_seconds", g["seconds_per_m2"]),
        ):
            if value is not None:
                group[key].append(value)
    return groups


SPACING_WORST = {
    "cell_gap": "gap_error_p95_mm",
    "cell_step": "step_error_p95_mm",
    "cell_sections": "sections_within_2sigma",
    "cell_ends": "seam_ends_within_2sigma",
    "seconds": "seconds_per_m2",
}
"""The per-cell figures a spacing's summary shows the worst of (summary key: row key)."""


def _band(spacing_mm: float) -> tuple[float, float, float]:
    """The targets (up to, measured share, error p95) of a spacing's band."""
    return next(t for t in SPACING_TARGETS if spacing_mm <= t[0] + 1e-9)


def _spacing_summary(rows: list[dict]) -> str:
    lines = [
        "| spacing mm | cells | sections measured (target) | gap / step err p95 mm, all "
        "sections (target) [worst cell] | within 2σ: sections / seam ends (target ≥ "
        f"{COVERAGE_TARGET:g}) [worst cell] | slowest s/m² (gauge) | gauge's gap err p95 mm "
        "[worst cell] |",
        "|---|---|---|---|---|---|---|",
    ]
    for spacing, group in sorted(_spacing_groups(rows).items()):
        _, share, p95 = _band(spacing)
        measured = group["measured"] / group["total"] if group["total"] else None
        worst = {key: max(group[key], default=None) for key in ("cell_gap", "cell_step")}
        least = {key: min(group[key], default=None) for key in ("cell_sections", "cell_ends")}
        lines.append(
            f"| {spacing:g} | {group['cells']} | {_fmt(measured)} (≥ {share:g}) "
            f"| {_fmt(error_p95(group['gap_mm']))} / {_fmt(error_p95(group['step_mm']))} (≤ {p95:g}) "
            f"[{_fmt(worst['cell_gap'])} / {_fmt(worst['cell_step'])}] "
            f"| {_fmt(within_2sigma(group['sections_sigma']), 2)} / "
            f"{_fmt(within_2sigma(group['seam_ends_sigma']), 2)} "
            f"[{_fmt(least['cell_sections'], 2)} / {_fmt(least['cell_ends'], 2)}] "
            f"| {_fmt(max(group['seconds'], default=None), 1)} "
            f"({_fmt(max(group['gauge_seconds'], default=None), 1)}) "
            f"| {_fmt(max(group['gauge_gap'], default=None))} |"
        )
    return "\n".join(lines)


ONE_PHASE_ANGLES_DEG = (0.0, 45.0)
"""Grid angles at which a square lattice crosses a seam at one phase (rows along it, or
its diagonals)."""


def _one_phase(row: dict) -> bool:
    """A cell whose corners (square edges, a chamfer's foot) every profile samples at one
    phase: no pooling places them finer than the spacing (s/√2 at 45°)."""
    return row.get("edge") in ("square", "chamfer") and any(
        abs(row["grid_angle_deg"] - angle) < 1e-9 for angle in ONE_PHASE_ANGLES_DEG
    )


def _angle_table(rows: list[dict]) -> str:
    """Per spacing and scan-grid angle, pooled over the edges and noise: sections measured,
    gap error p95 (mm) and sections within 2σ."""
    angles = sorted({r["grid_angle_deg"] for r in rows})
    lines = [
        "| spacing mm | " + " | ".join(f"{a:g}°" for a in angles) + " |",
        "|---|" + "---|" * len(angles),
    ]
    for spacing in sorted({r["spacing_mm"] for r in rows}):
        cells = []
        for angle in angles:
            group = _spacing_groups(
                [r for r in rows if r["spacing_mm"] == spacing and r["grid_angle_deg"] == angle]
            ).get(spacing)
            if group is None:
                cells.append("–")
                continue
            measured = group["measured"] / group["total"] if group["total"] else None
            cells.append(
                f"{_fmt(measured)} / {_fmt(error_p95(group['gap_mm']))} / "
                f"{_fmt(within_2sigma(group['sections_sigma']), 2)}"
            )
        lines.append(f"| {spacing:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _spacing_verdict(rows: list[dict]) -> dict[str, bool]:
    """Issue 54's targets at every spacing of each band, over all its cells' sections: the
    share measured, the gap and step error p95, and the share of sections' and seam ends'
    gaps within 2σ of the truth; and the speed target at 0.1 mm in every cell."""
    verdict = {}
    if _dense(rows):
        verdict[f"spacing sweep: ≤ {SECONDS_PER_M2:g} s per m² at 0.1 mm in every cell"] = (
            _fast_enough(rows)
        )
    groups = _spacing_groups(rows)
    low = 0.0
    for up_to, share, p95 in SPACING_TARGETS:
        band = [g for spacing, g in groups.items() if low < spacing <= up_to + 1e-9]
        name = f"spacing over {low:g} up to {up_to:g} mm" if low else f"spacing ≤ {up_to:g} mm"
        low = up_to
        if not band:
            continue
        verdict[f"{name}: ≥ {share:.0%} of sections measured at every spacing"] = all(
            g["total"] and g["measured"] >= share * g["total"] for g in band
        )
        verdict[f"{name}: gap and step error p95 ≤ {p95:g} mm at every spacing"] = all(
            value is not None and value <= p95
            for g in band
            for value in (error_p95(g["gap_mm"]), error_p95(g["step_mm"]))
        )
        verdict[f"{name}: ≥ {COVERAGE_TARGET:.0%} of gaps within 2σ at every spacing"] = all(
            value is not None and value >= COVERAGE_TARGET
            for g in band
            for value in (
                within_2sigma(g["sections_sigma"]),
                within_2sigma(g["seam_ends_sigma"]),
            )
        )
    return verdict
