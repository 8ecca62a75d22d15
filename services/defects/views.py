"""What a measurement's run page shows (``contract.views``): its headline figures, a table of
its seams (sections measured and unmeasured with why, gap and step mean/min/max with their
σ, the limits), its surface findings and junctions, and each seam's cross-sections — the
cloud's points across the seam at each section with the gap and step measured there, for
the page to step through along the seam; and its 3D scene (``contract.scene``): the cloud,
the panels' outlines and the seams. A comparison's page and scene: its alignment, regions,
findings and histogram; the scan coloured by deviation over its translucent nominal."""

from __future__ import annotations

import numpy as np

from contract.scene import JobScene, PointSet, Surface
from contract.views import (
    ColourScale,
    CrossSections,
    Figure,
    Figures,
    JobFiles,
    Picture,
    Pictures,
    Table,
    Thumbnails,
)
from services.defects.kinds import COMPARISON, DEVIATION_CLOUD, HISTOGRAM, RESULT
from services.defects.present import scene_lines

SLAB_MM = 0.6
"""Points within this of a section's plane (along the seam) are its cross-section."""
ACROSS_MM = 12.0
"""How far across the seam, each side, a cross-section reaches."""
HEIGHT_MM = 10.0
"""And how far above and below the seam's line."""
MOST_POINTS = 400
"""A cross-section's points at most (drawn at random, seeded: the page stays light)."""
THUMB_POINTS = 900
"""A surface finding's thumbnail: its surroundings' points at most."""
SURFACE_TYPES = ("dent", "bump", "scratch", "color")


def measure_view(files: JobFiles) -> list:
    result = files.json(RESULT.file_name())
    if result is None:
        return []
    seams = result.get("seams", [])
    limits = result.get("config") or {}  # its tolerances at the top, as CONFIG.json
    panels = [_figures(result), _seam_table(seams, limits)]
    surface = [f for f in result.get("findings", []) if f["type"] in SURFACE_TYPES]
    if surface:
        panels.append(_surface_table(surface))
    if result.get("junctions"):
        panels.append(_junction_table(result["junctions"]))
    clouds = list(files.inputs_of_kind("cloud").values())
    if len(clouds) == 1 and (seams or surface):
        from services.lib.pointcloud.ply import read_ply

        points = read_ply(clouds[0]).points.astype(np.float64)
        if seams:
            panels.append(CrossSections("Cross-sections", cross_sections(points, seams)))
        if surface:
            panels.append(Thumbnails("Surface findings up close", thumbnails(points, surface)))
    return panels


def _number(value: float | None, digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _figures(result: dict) -> Figures:
    seams = result.get("seams", [])
    measured = sum(s.get("sections_measured", 0) for s in seams)
    unmeasured = sum(s.get("sections_unmeasured", 0) for s in seams)
    return Figures(
        "Measurement",
        [
            Figure("points", result.get("points")),
            Figure("point spacing", result.get("point_spacing_mm"), "mm"),
            Figure("panels", len(result.get("panels", []))),
            Figure("seams", len(seams)),
            Figure("seams unmeasured", len(result.get("unmeasured_seams", []))),
            Figure("sections measured", measured),
            Figure("sections unmeasured", unmeasured),
            Figure("junctions", len(result.get("junctions", []))),
            Figure("out of tolerance", len(result.get("defects", []))),
            Figure("uncertain (within 2σ of a limit)", len(result.get("uncertain", []))),
        ],
    )


def _stats(stats: dict | None, sigma: float | None) -> str:
    if not stats:
        return "–"
    spread = f" (σ {_number(sigma)})" if sigma is not None else ""
    return (
        f"{_number(stats.get('mean'))} [{_number(stats.get('min'))} … "
        f"{_number(stats.get('max'))}]{spread}"
    )


def _why(seam: dict) -> str:
    if seam.get("unmeasured"):
        return seam["unmeasured"]
    reasons: dict[str, int] = {}
    for section in seam.get("sections", []):
        if section.get("unmeasured"):
            reasons[section["unmeasured"]] = reasons.get(section["unmeasured"], 0) + 1
    return "; ".join(f"{count} × {why}" for why, count in reasons.items()) or ""


def _seam_table(seams: list[dict], limits: dict) -> Table:
    gap = limits.get("gap_mm") or {}
    step = (limits.get("step_mm") or {}).get("max")
    parallelism = (limits.get("parallelism_mm") or {}).get("max")
    rows = [
        [
            f"seam {s['id']}",
            f"P{s['panels'][0]}–P{s['panels'][1]}",
            _number(s.get("length_mm"), 1),
            f"{s.get('sections_measured', 0)} / "
            f"{s.get('sections_measured', 0) + s.get('sections_unmeasured', 0)}",
            _why(s),
            _stats(s.get("gap_mm"), s.get("gap_sigma_mm")),
            _stats(s.get("step_mm"), s.get("step_sigma_mm")),
            _number(s.get("parallelism_mm")),
        ]
        for s in seams
    ]
    limit = (
        f"limits: gap {_number(gap.get('min'), 2)}–{_number(gap.get('max'), 2)} mm, "
        f"|step| ≤ {_number(step, 2)} mm, parallelism ≤ {_number(parallelism, 2)} mm"
    )
    return Table(
        "Seams",
        [
            "seam",
            "panels",
            "length mm",
            "sections measured",
            "unmeasured: why",
            "gap mm mean [min … max]",
            "step mm mean [min … max]",
            "parallelism mm",
        ],
        rows,
        note=limit,
    )


def _surface_table(findings: list[dict]) -> Table:
    rows = [
        [
            f["type"],
            f"{_number(f.get('value'))} {'ΔE' if f.get('unit') == 'delta_e' else 'mm'}",
            f"{_number(f.get('tolerance'))}",
            f.get("tolerance_state", ""),
            f.get("severity", ""),
            _number(f.get("extent_mm"), 1),
            ", ".join(_number(c, 1) for c in f.get("location", [])),
        ]
        for f in findings
    ]
    return Table(
        "Surface findings",
        ["type", "value", "limit", "state", "severity", "extent mm", "where (mm)"],
        rows,
    )


def _junction_table(junctions: list[dict]) -> Table:
    rows = [
        [
            f"junction {j['id']}",
            ", ".join(str(s) for s in j.get("seams", [])),
            ", ".join(_number(g) for g in j.get("gaps_mm", [])),
            f"{_number(j.get('mismatch_mm'))} (σ {_number(j.get('mismatch_sigma_mm'))})",
        ]
        for j in junctions
    ]
    return Table("Junctions", ["junction", "seams", "gaps mm", "mismatch mm"], rows)


def seam_frame(seam: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along, across, up) unit vectors of a seam: ``across`` points to its second panel
    (b lies on the + side of the cloud axis the across direction is nearest, RESULT.json's
    rule)."""
    along = np.subtract(seam["end"], seam["start"], dtype=float)
    along /= np.linalg.norm(along)
    up = np.asarray(seam["normal"], dtype=float)
    up = up - along * np.dot(up, along)
    up /= np.linalg.norm(up)
    across = np.cross(up, along)
    axis = int(np.argmax(np.abs(across)))
    if across[axis] < 0:
        across = -across
    return along, across, up


def cross_sections(points: np.ndarray, seams: list[dict]) -> list[dict]:
    """Each seam's sections with the cloud's points across it: ``u`` across the seam (mm,
    + towards its second panel), ``h`` up along its normal (mm), from the section's point."""
    rng = np.random.default_rng(0)
    out = []
    for seam in seams:
        along, across, up = seam_frame(seam)
        start = np.asarray(seam["start"], dtype=float)
        centre = (start + np.asarray(seam["end"], dtype=float)) / 2
        half = seam.get("length_mm", 0) / 2 + ACROSS_MM
        near = np.abs((points - centre) @ along) <= half  # the seam's box, once
        near &= np.abs((points - centre) @ across) <= ACROSS_MM
        near &= np.abs((points - centre) @ up) <= HEIGHT_MM
        local = points[near]
        sections = []
        for section in seam.get("sections", []):
            at = np.asarray(section["at"], dtype=float)
            offset = local - at
            slab = offset[np.abs(offset @ along) <= SLAB_MM]
            if len(slab) > MOST_POINTS:
                slab = slab[np.sort(rng.choice(len(slab), MOST_POINTS, replace=False))]
            u, h = slab @ across, slab @ up
            order = np.argsort(u)
            sections.append(
                {
                    "along_mm": round(float(np.dot(at - start, along)), 1),
                    "gap_mm": section.get("gap_mm"),
                    "gap_sigma_mm": section.get("gap_sigma_mm"),
                    "step_mm": section.get("step_mm"),
                    "edges": section.get("edges", []),
                    "unmeasured": section.get("unmeasured"),
                    "u_mm": np.round(u[order], 3).tolist(),
                    "h_mm": np.round(h[order], 3).tolist(),
                }
            )
        out.append(
            {
                "seam": seam["id"],
                "panels": seam["panels"],
                "length_mm": seam.get("length_mm"),
                "sections": sections,
            }
        )
    return out


def thumbnails(points: np.ndarray, findings: list[dict]) -> list[dict]:
    """Each surface finding's surroundings seen from above its surface: ``u``, ``v`` in its
    plane and ``h`` off it (mm, from the finding's place), within twice its extent; the
    page draws them coloured by ``h`` (or by the scan's colour difference for a patch,
    which shows as height here: what the cloud holds)."""
    rng = np.random.default_rng(0)
    out = []
    for finding in findings:
        at = np.asarray(finding["location"], dtype=float)
        normal = np.asarray(finding["normal"], dtype=float)
        normal /= np.linalg.norm(normal)
        helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(normal, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(normal, e1)
        reach = max(2.0 * float(finding.get("extent_mm") or 0.0), 6.0)
        offset = points - at
        u, v, h = offset @ e1, offset @ e2, offset @ normal
        near = (np.abs(u) <= reach) & (np.abs(v) <= reach) & (np.abs(h) <= 5.0)
        index = np.flatnonzero(near)
        if len(index) > THUMB_POINTS:
            index = np.sort(rng.choice(index, THUMB_POINTS, replace=False))
        unit = "ΔE" if finding.get("unit") == "delta_e" else "mm"
        out.append(
            {
                "label": f"{finding['type']} {_number(finding.get('value'))} {unit} "
                f"({finding.get('tolerance_state', '')}, {finding.get('severity', '')})",
                "reach_mm": round(reach, 1),
                "u_mm": np.round(u[index], 2).tolist(),
                "v_mm": np.round(v[index], 2).tolist(),
                "h_mm": np.round(
                    h[index] - np.median(h[index]) if len(index) else h[index], 3
                ).tolist(),
            }
        )
    return out


def measure_scene(files: JobFiles, max_points: int) -> JobScene:
    """The measured cloud (at most ``max_points``, drawn at random, seeded) with the
    panels' outlines and the seams, in the cloud's frame."""
    from services.lib.pointcloud.ply import read_ply

    result_path = files.outputs.get(RESULT.file_name())
    if result_path is None:
        raise ValueError("the run wrote no defects.json")
    clouds = list(files.inputs_of_kind("cloud").values())
    points: tuple[PointSet, ...] = ()
    if len(clouds) == 1:
        cloud = read_ply(clouds[0])
        keep = np.arange(len(cloud.points))
        if len(keep) > max_points:
            keep = np.sort(np.random.default_rng(0).choice(len(keep), max_points, replace=False))
        colours = None if cloud.colors is None else cloud.colors[keep]
        points = (PointSet("cloud", cloud.points[keep].astype(np.float64), colours),)
    return JobScene(
        lines=scene_lines(result_path),
        points=points,
        frame="the cloud's frame (the robot's base, mm)",
        extras={  # the lines' colours are named by their materials
            "figures": {k: v for k, v in files.result.items() if not isinstance(v, dict | list)}
        },
    )


def compare_view(files: JobFiles) -> list:
    """A comparison's page: the alignment, each region, the findings and the histogram."""
    result = files.json(COMPARISON.file_name())
    if result is None:
        return []
    alignment = result["alignment"]
    sigma = alignment["pose_sigma"]
    figures = Figures(
        "Comparison with the nominal",
        [
            Figure("points", result["points"]),
            Figure("point spacing", result["spacing_mm"], "mm"),
            Figure("strays (beyond 25 mm)", result["strays"]),
            Figure(
                "nominal",
                f"{result['nominal']['file']} ({result['nominal']['format']}, "
                f"{result['nominal']['triangles']} triangles)",
            ),  # fmt: skip
            Figure("profile band", "{:+.3f} … {:+.3f}".format(*result["profile_band_mm"]), "mm"),
            Figure("alignment", alignment["method"]),
            Figure("residual, robust σ", alignment["residual_robust_mm"], "mm"),
            Figure("residual, RMS", alignment["residual_rms_mm"], "mm"),
            Figure(
                "moved / turned by the fit",
                f"{alignment['moved_mm']:.3f} mm / {alignment['turned_deg']:.4f}°",
            ),  # fmt: skip
            Figure("pose 1σ", ", ".join(f"{k} {v:.2g}" for k, v in sigma.items())),
            Figure("beyond the band", len(result["defects"])),
            Figure("uncertain (within 2σ of the band)", len(result["uncertain"])),
        ],
    )
    panels: list = [figures]
    warnings = alignment["warnings"] + result.get("warnings", [])
    if warnings:
        panels.append(Table("Warnings", ["before reading it as a pass"], [[w] for w in warnings]))
    panels.append(
        Table(
            "Regions of the nominal",
            ["region", "points", "mean mm", "σ mm", "min mm", "max mm", "within band", "covered"],
            [
                [
                    r["region"],
                    r["points"],
                    r["mean_mm"],
                    r["sigma_mm"],
                    r["min_mm"],
                    r["max_mm"],
                    _share(r["within_share"]),
                    _share(r["coverage_share"]),
                ]
                for r in result["regions"]
            ],  # fmt: skip
            note="covered: the share of the region's area within three point spacings of a "
            "scan point",
        )
    )
    findings = result["defects"] + result["uncertain"]
    if findings:
        panels.append(
            Table(
                "Deviations beyond the band",
                ["region", "peak mm", "where (mm)", "mean mm", "area mm²", "severity", "state"],
                [
                    [
                        f["region"],
                        f["value"],
                        ", ".join(f"{v:.1f}" for v in f["location"]),
                        f["mean_mm"],
                        f["area_mm2"],
                        f["severity"],
                        f["tolerance_state"],
                    ]
                    for f in findings
                ],  # fmt: skip
            )
        )
    scale = result["color_scale_mm"]
    panels.append(
        Pictures(
            "Deviation",
            [
                Picture(
                    "histogram of the deviations, the band dashed",
                    [HISTOGRAM.file_name()],
                    ["histogram"],
                    layer_scales=[
                        ColourScale(list(DEVIATION_COLOURS), f"−{scale:g} mm", f"+{scale:g} mm")
                    ],
                )
            ],
        )
    )
    return panels


DEVIATION_COLOURS = ("#2166ac", "#f7f7f7", "#b2182b")
"""The deviation's colours, below the nominal to above it (``compare.deviation_colours``)."""
NOMINAL_RGBA = (0.75, 0.78, 0.82, 0.35)
"""The nominal, translucent behind the scan's colours."""
MOST_TRIANGLES = 1_000_000
"""A nominal shown in 3D has at most this many triangles (beyond, it is left out, said so)."""


def _share(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.1f} %"


def compare_scene(files: JobFiles, max_points: int) -> JobScene:
    """The aligned scan coloured by its deviation (at most ``max_points``, seeded) and the
    nominal, translucent, in the nominal's frame."""
    from services.lib.pointcloud.nominal import read_nominal
    from services.lib.pointcloud.ply import read_ply

    cloud_path = files.outputs.get(DEVIATION_CLOUD.file_name())
    result = files.json(COMPARISON.file_name())
    if cloud_path is None or result is None:
        raise ValueError("the run wrote no deviation.ply")
    cloud = read_ply(cloud_path)
    keep = np.arange(len(cloud.points))
    if len(keep) > max_points:
        keep = np.sort(np.random.default_rng(0).choice(len(keep), max_points, replace=False))
    points = PointSet("deviation", cloud.points[keep].astype(np.float64), cloud.colors[keep])
    surfaces: tuple[Surface, ...] = ()
    extras: dict = {
        "figures": {k: v for k, v in files.result.items() if not isinstance(v, dict | list)},
        "deviation_scale_mm": [-result["color_scale_mm"], result["color_scale_mm"]],
        "deviation_colours": list(DEVIATION_COLOURS),
        "profile_band_mm": result["profile_band_mm"],
        "alignment": result["alignment"]["method"],
        "residual_mm": result["alignment"]["residual_robust_mm"],
    }
    nominals = list(files.inputs_of_kind("nominal").values())
    if len(nominals) == 1:
        nominal = read_nominal(nominals[0])
        if len(nominal.mesh.faces) <= MOST_TRIANGLES:
            surfaces = (
                Surface("nominal", np.asarray(nominal.mesh.vertices_mm), np.asarray(nominal.mesh.faces),
                        NOMINAL_RGBA, {"regions": list(nominal.regions[:200])}),
            )  # fmt: skip
        else:
            extras["nominal"] = (
                f"{len(nominal.mesh.faces)} triangles: not drawn (at most {MOST_TRIANGLES})"
            )
    return JobScene(
        points=(points,),
        surfaces=surfaces,
        frame="the nominal's frame (mm)",
        extras=extras,
    )
