"""``vista defects measure``, ``vista defects simulate`` and ``vista defects bench`` (and
their old spellings ``vista measure``, ``vista simulate defects``, ``vista bench defects``)."""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from contract.cli import alias, fail, params_options, progress_bar
from contract.tolerances import Tolerances, finding_line
from services.defects.kinds import CompareParams, MeasureParams, MeasureSettings
from services.lib.wording import counted

if TYPE_CHECKING:
    from services.defects.run import Measured
    from services.defects.truth import Truth

# Heavy imports (numpy, scipy, open3d) stay inside the commands.


@params_options(MeasureParams, fixed={"keep_in_tolerance": True})
def measure(
    ctx: typer.Context,
    cloud: Path = typer.Argument(
        ...,
        help="Stitched cloud, e.g. from `vista stitching stitch`: PLY (mm), or PCD, LAS/LAZ, "
        "E57, XYZ/ASC, PTS in their formats' units.",
    ),
    config: Path = typer.Option(
        None,
        "--config",
        help="CONFIG.json: tolerances and measurement settings (defaults if omitted); an "
        "option below given on the command line overrides its setting.",
    ),
    out: Path = typer.Option(..., "-o", "--out", help="Where to write RESULT.json."),
    plot: Path = typer.Option(None, help="Also write the gap/step profiles as a PNG."),
    truth: Path = typer.Option(
        None, help="truth.json of `vista defects simulate`: prints the errors against it."
    ),
    threads: int = typer.Option(
        None, min=1, max=256, help="Threads to measure on (default: one per available core)."
    ),
    *,
    params: MeasureParams,
) -> None:
    """Measure every seam (gap, step, parallelism), junction (mismatch) and surface defect
    (dents, bumps, scratches, colour) of a panel-assembly cloud against the tolerances."""
    from services.defects.config import read_config
    from services.defects.measure import MeasureError
    from services.defects.run import measure_cloud
    from services.defects.truth import Truth
    from services.lib.process import available_cores, prepare_process

    prepare_process()
    try:
        tolerances, settings = read_config(
            config, params, _typed(ctx, MeasureSettings.model_fields)
        )
        true = None if truth is None else Truth.read(truth)
    except ValueError as exc:  # ConfigError, a JSON's, a truth document's
        fail(str(exc))
    with progress_bar("measuring") as step:
        try:
            measured = measure_cloud(
                cloud,
                tolerances,
                settings,
                threads=threads or available_cores(),
                progress=step,
            )
        except (MeasureError, OSError) as exc:  # a cloud not read, or no panel assembly
            fail(str(exc))
    document = measured.document
    if true is not None:
        document = {**document, "truth_evaluation": _evaluation(measured, true)}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(document, indent=1) + "\n")
    _echo_measurement(measured, _seconds_since_start())
    if plot is not None:
        measured.draw_profiles(plot)
        typer.echo(f"wrote {plot}")
    typer.echo(f"wrote {out}")
    if true is not None:
        typer.echo("\n".join(_truth_lines(document["truth_evaluation"], out)))


def _simulate_part(out_dir: Path, name: str, spacing_mm: float, seed: int) -> None:
    from services.defects.nominal_parts import PARTS, make_part, write_part

    if name not in PARTS:
        fail(f"--part: unknown {name!r}; known: {', '.join(PARTS)}")
    made = make_part(name, seed=seed, spacing_mm=max(spacing_mm, 0.3), warp_mm=0.3)
    written = write_part(out_dir, made)
    typer.echo(f"wrote {', '.join(str(p) for p in written)} ({len(made.points_mm)} points)")
    typer.echo(
        f"compare it: vista defects compare {written[0]} {written[1]} -o {out_dir}/result.json"
    )
    if written[-1].suffix == ".step":  # a solid: its back faces are there too
        typer.echo(
            f"against the CAD solid: vista defects compare {written[0]} {written[-1]} "
            f"--align points --reference-points {out_dir}/points.json -o {out_dir}/result.json"
        )


def _reference_points(path: str) -> dict:
    """POINTS.json: {"nominal": {name: [x, y, z]}, "scan": {name: [x, y, z]}} in mm."""
    from services.lib.archive import read_json

    return read_json(Path(path))


POINTS_HELP = (
    'POINTS.json for --align points: {"nominal": {name: [x, y, z]}, "scan": {name: '
    "[x, y, z]}} in mm — the nominal's reference points and the same points picked on the "
    "scan (3-2-1 / RPS; at least three)."
)


@params_options(CompareParams, text={"reference_points": (POINTS_HELP, _reference_points)})
def compare(
    cloud: Path = typer.Argument(
        ..., help="The scan: PLY (mm), or PCD, LAS/LAZ, E57, XYZ/ASC, PTS in their units."
    ),
    nominal: Path = typer.Argument(
        ...,
        help="The part's nominal: STL (binary or ASCII), OBJ, PLY mesh, glTF/GLB (metres) "
        "or STEP (tessellated to 0.01 mm).",
    ),
    config: Path = typer.Option(
        None,
        "--config",
        help='CONFIG.json: the tolerances, as for `measure`, with profile_mm ({"max": m} '
        'for ±m, {"min": a, "max": b}, and "regions": {name: {…}} for regions of '
        "the nominal); default ±0.5 mm.",
    ),
    out: Path = typer.Option(
        ...,
        "-o",
        "--out",
        help="RESULT.json to write; beside it RESULT.ply (the aligned cloud coloured by "
        "deviation, its scalar field `deviation`), RESULT.regions.csv and RESULT.png "
        "(the histogram).",
    ),
    threads: int = typer.Option(
        None, min=1, max=256, help="Threads to compare on (default: one per available core)."
    ),
    *,
    params: CompareParams,
) -> None:
    """Compare a scan with its part's nominal (CAD): align it (given, best fit or
    reference points), measure each point's signed deviation, and report every region's
    statistics and coverage and every area beyond the profile band."""
    from services.defects.compare import CompareError, compare_cloud
    from services.defects.config import config_parts
    from services.lib.archive import read_json
    from services.lib.process import available_cores, prepare_process

    prepare_process()
    try:
        tolerances = (
            Tolerances() if config is None else config_parts(read_json(config), str(config))[0]
        )
    except ValueError as exc:
        fail(str(exc))
    with progress_bar("comparing") as step:
        try:
            compared = compare_cloud(
                cloud, nominal, tolerances, params, threads=threads or available_cores(),
                progress=step,
            )  # fmt: skip
        except (CompareError, OSError) as exc:
            fail(str(exc))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(compared.document, indent=1) + "\n")
    written = [
        out,
        out.with_suffix(".ply"),
        out.with_suffix(".regions.csv"),
        out.with_suffix(".png"),
    ]
    compared.write_cloud(written[1])
    written[2].write_text(compared.region_table())
    compared.write_histogram(written[3])
    _echo_comparison(compared.document)
    for path in written:
        typer.echo(f"wrote {path}")


ECHOED_REGIONS = 12
"""Regions printed (the most scanned first); a STEP may have hundreds."""


def _echo_comparison(document: dict) -> None:
    """RESULT.json in lines: the alignment, each region, the findings."""
    alignment = document["alignment"]
    sigma = alignment["pose_sigma"]
    typer.echo(
        f"{document['points']} points (spacing {document['spacing_mm']:.3f} mm, "
        f"{document['strays']} strays) against {document['nominal']['triangles']} triangles "
        f"in {sum(document['seconds'].values()):.2f} s"
    )
    typer.echo(
        f"aligned ({alignment['method']}): residual rms {alignment['residual_rms_mm']:.4f} mm, "
        f"robust σ {alignment['residual_robust_mm']:.4f} mm; moved "
        f"{alignment['moved_mm']:.3f} mm, turned {alignment['turned_deg']:.4f}°; pose 1σ "
        + ", ".join(f"{k} {v:.2g}" for k, v in sigma.items())
    )
    for warning in alignment["warnings"] + document["warnings"]:
        typer.echo(f"WARNING: {warning}")
    band = document["profile_band_mm"]
    regions = sorted(document["regions"], key=lambda r: -r["points"])
    for region in regions[:ECHOED_REGIONS]:
        if not region["points"]:
            typer.echo(
                f"  {region['region']}: not scanned (coverage {region['coverage_share']:.0%})"
            )
            continue
        typer.echo(
            f"  {region['region']}: {region['points']} points, mean {region['mean_mm']:+.3f}, "
            f"σ {region['sigma_mm']:.3f}, {region['min_mm']:+.3f} … {region['max_mm']:+.3f} mm; "
            f"{region['within_share']:.1%} within {region['band_mm'][0]:+.2f} … "
            f"{region['band_mm'][1]:+.2f}; covered {region['coverage_share']:.0%}"
        )
    if len(regions) > ECHOED_REGIONS:
        rest = regions[ECHOED_REGIONS:]
        typer.echo(
            f"  … and {len(rest)} more regions with {sum(r['points'] for r in rest)} points "
            "(every region: RESULT.regions.csv)"
        )
    found = document["defects"]
    typer.echo(
        f"{counted(len(found), 'deviation')} out of the profile band ({band[0]:+.2f} … "
        f"{band[1]:+.2f} mm by default)" + (":" if found else ".")
    )
    for finding in found + document["uncertain"]:
        state = " UNCERTAIN" if finding["tolerance_state"] == "uncertain" else ""
        typer.echo(
            f"  {finding['region']}: peak {finding['value']:+.3f} mm at "
            f"{[round(v, 1) for v in finding['location']]}, mean {finding['mean_mm']:+.3f} mm "
            f"over {finding['area_mm2']:.0f} mm² — {finding['severity']}{state}"
        )


def _typed(ctx: typer.Context, names: Iterable[str]) -> set[str]:
    """Those of ``names`` whose options were given on the command line."""
    sources = {name: ctx.get_parameter_source(name) for name in names}
    return {name for name, source in sources.items() if source and source.name == "COMMANDLINE"}


def _echo_measurement(measured: Measured, waited: float | None) -> None:
    """The measurement in lines: the counts and time, each panel, seam and junction, the
    unmeasured seams, the defects and the uncertain findings (as RESULT.json has them)."""
    result, document, limits = measured.result, measured.document, measured.config.tolerances
    typer.echo(
        f"{result.point_count} points (spacing {result.spacing_mm:.3f} mm), "
        f"{counted(len(result.panels), 'panel')} ({result.panel_area_m2:.4f} m²), "
        f"{counted(len(result.seams), 'seam')}, {counted(len(result.junctions), 'junction')}; "
        f"measured in {sum(result.seconds.values()):.2f} s"
        + (
            f" ({waited:.2f} s since the command started, reading the cloud included)"
            if waited
            else ""
        )
    )
    for panel in document["panels"]:
        typer.echo(
            f"  panel {panel['id']}: centre {[round(v, 1) for v in panel['centroid']]}, "
            f"{panel['area_mm2'] / 100:.0f} cm²"
        )
    for seam in document["seams"]:
        typer.echo("  " + _seam_line(seam))
    for junction in document["junctions"]:
        typer.echo(
            f"  junction {junction['id']} seams {junction['seams']}: mismatch {junction['mismatch_mm']:.3f} mm"
        )
    unmeasured = document["unmeasured_seams"]
    if unmeasured:  # never a plain summary: their gaps were not judged
        typer.echo(
            f"WARNING: {len(unmeasured)} of {counted(len(document['seams']), 'seam')} "
            "unmeasured: their gap, parallelism and mismatch are not judged (why: above)"
        )
    found = len(document["defects"])
    typer.echo(f"{counted(found, 'defect')} out of tolerance" + (":" if found else "."))
    for d in document["defects"]:
        typer.echo(
            "  "
            + finding_line(d["type"], d["value"], d.get("panels"), limits)
            + f" {d['severity']:<8} confidence {d['confidence']:.2f} at {[round(v, 1) for v in d['location']]}"
        )
    unsure = document["uncertain"]
    if unsure:
        typer.echo(f"{counted(len(unsure), 'finding')} within 2σ of a limit (uncertain):")
    for d in unsure:
        typer.echo(
            "  "
            + finding_line(d["type"], d["value"], d.get("panels"), limits)
            + f" ± {d['sigma_mm']:.3f} (1σ) UNCERTAIN — {d['measurements']['advice']}"
        )


def _evaluation(measured: Measured, true: Truth) -> dict:
    """The measurement against the simulation's truth (RESULT.json's truth_evaluation)."""
    from services.defects.evaluate import evaluate

    return evaluate(measured.result, true, measured.config.tolerances).summary()


def _truth_lines(summary: dict, out: Path) -> list[str]:
    """The evaluation against the truth in a few lines (errors in mm), and where the rest
    is."""

    def mm(value: float | None) -> str:
        return "–" if value is None else f"{value:.3f}"

    def share(value: float | None) -> str:
        return "–" if value is None else f"{value:.0%}"

    def hits(counts: dict) -> str:
        return ", ".join(
            f"{kind} {c['tp']}/{c['tp'] + c['fn']} found, {c['fp']} false"
            for kind, c in counts.items()
        )

    return [
        f"against the truth: seams {summary['seams']}, junctions {summary['junctions']}; "
        f"{summary['sections']} of {summary['sections_total']} sections measured "
        f"({share(summary['unmeasured_share'])} unmeasured)",
        f"  gap error mean {mm(summary['gap_error_mean_mm'])}, p95 {mm(summary['gap_error_p95_mm'])}, "
        f"max {mm(summary['gap_error_max_mm'])} mm; step mean {mm(summary['step_error_mean_mm'])}, "
        f"p95 {mm(summary['step_error_p95_mm'])} mm",
        f"  parallelism p95 {mm(summary['parallelism_error_p95_mm'])} mm, mismatch p95 "
        f"{mm(summary['mismatch_error_p95_mm'])} mm",
        f"  out of tolerance: {hits(summary['geometric']) or 'none'}",
        f"  surface: {hits(summary['surface']) or 'none'}",
        f"the whole evaluation: {out} (truth_evaluation)",
    ]


def _seconds_since_start() -> float | None:
    """Wall time since this process started (Linux: interpreter start-up and imports
    included), or None where that cannot be read."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        uptime_s = float(Path("/proc/uptime").read_text().split()[0])
        return uptime_s - int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def _seam_line(seam: dict) -> str:
    """One seam of RESULT.json as a line: its edges, gap, step and unmeasured sections."""
    edges = " | ".join(
        e["model"]
        + (f" r {e['radius_mm']:.2f}" if "radius_mm" in e else "")
        + (f" {e['angle_deg']:.0f}°" if "angle_deg" in e else "")
        + (f" burr {e['burr_mm']:.2f}" if "burr_mm" in e else "")
        for e in seam["edges"]
    )
    s = seam["step_mm"]
    head = f"seam {seam['id']} panels {seam['panels']} ({edges}): {seam['length_mm']:.1f} mm, "
    missing = seam["sections_unmeasured"]
    total = missing + seam["sections_measured"]
    tail = f", {missing} of {total} sections unmeasured" if missing else ""
    if seam["unmeasured"]:
        return head + f"UNMEASURED — {seam['unmeasured']}"
    g = seam["gap_mm"]
    return (
        head + f"gap {g['min']:.3f}/{g['mean']:.3f}/{g['max']:.3f}, step {s['min']:+.3f}…"
        f"{s['max']:+.3f}, parallelism {seam['parallelism_mm']:.3f} (min/mean/max, mm){tail}"
    )


def simulate_defects(
    out_dir: Path = typer.Argument(..., help="Folder to write the example into."),
    rows: int = typer.Option(2, min=1, max=4, help="Panel rows."),
    cols: int = typer.Option(2, min=1, max=4, help="Panel columns (rows × cols: 2 to 12)."),
    panel_mm: tuple[float, float] = typer.Option((150.0, 100.0), help="Panel size (mm)."),
    radius_mm: float = typer.Option(
        0.0, help="Sidewall curvature radius (mm) of the assembly; 0 = flat."
    ),
    spacing_mm: float = typer.Option(
        0.1, min=0.05, max=1.0, help="Sensor sampling on the part (0.1 mm ≈ a Gocator 3210)."
    ),
    edge: list[str] = typer.Option(
        ["round"],
        help="Edge profiles the panels are drawn from (repeat the option for a mix): "
        "round (r 0.5–2 mm), chamfer (0.3–1 mm × 45°), square.",
    ),
    seed: int = typer.Option(0, help="Random seed."),
    part: str = typer.Option(
        None,
        help="Instead of an assembly, one part scanned against its nominal: panel (a "
        "warped, dented skin panel), angle (a twisted angle profile) or plate (a hole "
        "drilled 6 mm off); writes cloud.ply, nominal.stl, nominal.step and truth.json.",
    ),
) -> None:
    """Write a simulated panel assembly with seams (gap, taper, step; rounded, chamfered or
    square edges), dents, bumps, scratches and colour patches: calibration pairs, coloured
    scans, the merged cloud, its nominal (nominal.stl, a solid per panel), default
    tolerances and the ground truth — or, with --part, one part and its nominal."""
    from services.defects.example import write_defects_example
    from services.defects.simulate import EDGE_KINDS, AssemblySpec

    if part is not None:
        _simulate_part(out_dir, part, spacing_mm, seed)
        return

    if not 2 <= rows * cols <= 12:
        fail(f"an assembly has 2 to 12 panels; --rows {rows} × --cols {cols} = {rows * cols}")
    unknown = sorted(set(edge) - set(EDGE_KINDS))
    if unknown:
        fail(f"--edge: unknown {unknown}; known: {list(EDGE_KINDS)}")
    grid = (int(round(100 / spacing_mm)), int(round(154 / spacing_mm)))
    spec = AssemblySpec(
        rows=rows,
        cols=cols,
        panel_mm=panel_mm,
        radius_mm=radius_mm or None,
        edge_kinds=tuple(dict.fromkeys(edge)),
    )
    example = write_defects_example(out_dir, spec, grid=grid, seed=seed, progress=typer.echo)
    typer.echo(
        f"wrote {out_dir}: {counted(example.scans, 'scan')}, cloud.ply ({example.cloud_points} "
        f"points), {counted(example.panels, 'panel')}, {counted(example.seams, 'seam')}, "
        f"{counted(example.junctions, 'junction')}, {counted(example.defects, 'surface defect')} "
        "in truth.json, config.json"
    )
    typer.echo(
        f"measure it: vista defects measure {out_dir}/cloud.ply --config {out_dir}/config.json "
        f"-o {out_dir}/result.json --truth {out_dir}/truth.json"
    )


def bench_defects(
    out: Path = typer.Option(Path("bench-results/defects.json"), help="Where to write the JSON."),
    seeds: int = typer.Option(2, min=1, help="Simulated assemblies per case."),
    seed: int = typer.Option(0, help="Random seed."),
    sweep: list[str] = typer.Option(
        ["assemblies", "edges"],
        help="Which sweeps: `assemblies` (gap, step, taper, noise, curvature, density; "
        "detection), `edges` (edge types, tilted views and sensor artefacts), `spacing` "
        "(every spacing × edge type × scan-grid angle × noise: 168 cells, hours) and/or "
        "`nominal` (parts against their nominal; the distance beside CloudCompare's C2M "
        "and Open3D's).",
    ),
    nominal_points: int = typer.Option(
        10_000_000, min=1000, help="Points of the nominal sweep's distance comparison."
    ),
    spacing: list[float] = typer.Option(
        None,
        min=0.05,
        max=1.0,
        help="The spacing sweep's point spacings (mm; repeat; default 0.05 0.1 0.2 0.3 0.5 "
        "0.75 1.0).",
    ),
    grid_angle: list[float] = typer.Option(
        None,
        min=0.0,
        max=90.0,
        help="The spacing sweep's scan-grid angles to the seams (degrees; repeat; default 0 "
        "2 15 45).",
    ),
    noise: list[float] = typer.Option(
        None,
        min=0.0,
        max=0.5,
        help="The spacing sweep's noise σ (mm; repeat; default 0.02 0.05).",
    ),
) -> None:
    """Gap, step, parallelism and mismatch accuracy against ground truth over a sweep (gap,
    step, taper, edge radius, noise, curvature, density) with a single-profile gauge as the
    peer; detection precision/recall per defect type; seconds per m²; and an edge sweep
    (square, chamfered, rounded and mixed edges, tilted views, dropout, burrs, narrow gaps,
    mixed pixels, dark patches, misregistration, shadowed corners) with the share of
    sections left unmeasured; and a spacing sweep (0.05–1 mm, every edge type, scan grid
    at 0–45° to the seams, two noise levels) with the share measured, the errors, the
    σ's coverage and the speed, the gauge beside each. Prints tables, writes JSON."""
    from services.defects.bench import (
        GRID_ANGLES_DEG,
        SPACING_NOISE_MM,
        SPACINGS_MM,
        SWEEPS,
        run_defects_bench,
        spacing_cases,
    )

    unknown = sorted(set(sweep) - set(SWEEPS))
    if unknown:
        fail(f"--sweep: unknown {unknown}; known: {sorted(SWEEPS)}")
    cells = spacing_cases(
        tuple(spacing or SPACINGS_MM),
        tuple(grid_angle or GRID_ANGLES_DEG),
        tuple(noise or SPACING_NOISE_MM),
    )
    run_defects_bench(out, seeds=seeds, seed=seed, sweeps=tuple(sweep), spacing_sweep=cells,
                      nominal_points=nominal_points)  # fmt: skip


def register(app: typer.Typer, simulate_app: typer.Typer, bench_app: typer.Typer) -> None:
    defects_app = typer.Typer(
        help="Gaps, steps, parallelism, mismatch and surface defects of a stitched cloud.",
        no_args_is_help=True,
    )
    verbs = {
        "measure": measure,
        "compare": compare,
        "simulate": simulate_defects,
        "bench": bench_defects,
    }
    for verb, command in verbs.items():
        defects_app.command(verb)(command)
    app.add_typer(defects_app, name="defects")
    alias(app, "measure", measure, "defects measure")
    alias(simulate_app, "defects", simulate_defects, "defects simulate")
    alias(bench_app, "defects", bench_defects, "defects bench")
