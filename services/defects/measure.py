"""Measure a stitched cloud of a panel assembly: seams (gap, step, parallelism),
junctions (mismatch) and surface defects, judged against the tolerances.

Pipeline: surface frame → height map → panels → seam lines and junctions → sections
(points) → per-seam profiles → surface defects → findings out of tolerance become
defects. All lengths in mm; points in the cloud's frame.
"""

from __future__ import annotations

import re
import time
from concurrent.futures import Executor, ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass, replace
from math import erf, sqrt

import numpy as np
from scipy import ndimage

from contract.findings import (
    FindingMeasurements,
    JunctionMeasurements,
    SeamMeasurements,
    Stats,
    revised,
)
from contract.tolerances import advice, judge, severity, tolerance_state, upper_limit
from contract.vocabulary import Progress
from services.defects import binning
from services.defects.config import MeasureConfig
from services.defects.panels import PanelShape, describe_panels, segment_panels
from services.defects.raster import Raster, SurfaceFrame, fit_frame, point_spacing_mm, rasterize
from services.defects.seams import Junction, SeamLine, find_junctions, find_seams
from services.defects.sections import (
    EdgeShape,
    SeamProfile,
    SectionConfig,
    edge_reach_mm,
    profile_seam,
    reach_mm,
    section_range,
    slab_width_mm,
)
from services.defects.surface import SurfaceFinding, block_lab, find_surface_defects
from services.lib.pointcloud.ply import PointCloud
from services.lib.tasks import helping_map, start_helping
from services.lib.wording import counted

MAX_CELLS = 60e6
"""Largest height map measured (2.4 m² at 0.2 mm cells; ~2 GB of work arrays)."""
MIN_SIGMA_MM = 0.005


class MeasureError(ValueError):
    """The cloud cannot be measured (too few points, no panels)."""


@dataclass(frozen=True)
class SeamResult:
    id: int
    panels: tuple[int, int]
    """(a, b) panel ids: b lies on the side of the cloud axis the seam's across direction
    is closest to (``_oriented``); the step is b's top over a's."""
    start: np.ndarray
    end: np.ndarray
    length_mm: float
    gap_mm: Stats | None
    """Over the measured sections; None if the seam is unmeasured."""
    step_mm: Stats
    """Over the sections whose two tops were fitted."""
    gap_at_ends_mm: tuple[float, float] | None
    """The gap line fitted along the seam, at its start and end."""
    parallelism_mm: float | None
    gap_sigma_mm: float
    """Scatter of the section gaps about that line (or their own σ, if larger)."""
    step_sigma_mm: float
    edges: tuple[EdgeShape, EdgeShape]
    """Each side's edge model and shape."""
    noise_mm: float
    """σ of the points about the panel tops along the seam (from the data)."""
    normal: np.ndarray
    sections_at: np.ndarray
    """(K, 3) section centres, every section."""
    sections_gap_mm: np.ndarray
    """(K,) NaN where unmeasured."""
    sections_step_mm: np.ndarray
    sections_gap_sigma_mm: np.ndarray
    sections_models: np.ndarray
    """(K, 2) edge model index (``edges.MODELS``) of side a and b."""
    sections_residual_mm: np.ndarray
    sections_unmeasured: tuple[str | None, ...]
    unmeasured: str | None
    """Why the seam as a whole yields no gap or parallelism (too few measured sections)."""
    edge_sampling_mm: float = np.nan
    """The widest stretch its sections' pooled profiles leave near the tops' ends (median):
    about a spacing where every profile samples the edges at one place."""

    @property
    def measured(self) -> np.ndarray:
        """(K,) bool: sections whose gap is measured."""
        return np.isfinite(self.sections_gap_mm)


@dataclass(frozen=True)
class JunctionResult:
    id: int
    at: np.ndarray
    seams: tuple[int, ...]
    gaps_mm: tuple[float, ...]
    """Each seam's gap where it meets the junction."""
    mismatch_mm: float
    mismatch_sigma_mm: float


@dataclass(frozen=True)
class Finding:
    """A measurement out of tolerance (a defect) or a surface detection."""

    type: str
    value: float
    unit: str
    """``mm``, or ``delta_e`` for colour."""
    tolerance: float
    location: np.ndarray
    normal: np.ndarray
    extent_mm: float
    severity: str
    """info (within tolerance), minor, major, critical."""
    confidence: float
    source: dict
    """Which seam (and its panels), junction (and its seams) or panel it was found on."""
    measurements: FindingMeasurements
    """Its family's model (``contract.findings``): what it was judged on and how."""
    sigma_mm: float | None = None
    """1σ of the value (a seam's or junction's measurement); None for surface findings."""
    state: str = ""
    """``contract.tolerances.tolerance_state`` given ``sigma_mm``: out, within or
    uncertain ('': by the severity alone)."""

    @property
    def out_of_tolerance(self) -> bool:
        return self.state == "out" if self.state else self.severity != "info"

    @property
    def uncertain(self) -> bool:
        return self.state == "uncertain"


@dataclass(frozen=True)
class PanelResult:
    """A panel a reader can find: in the cloud's frame, mm."""

    id: int
    centroid: np.ndarray
    bounds_min: np.ndarray
    bounds_max: np.ndarray
    normal: np.ndarray
    """Unit normal of its top, towards the sensor (the cloud's normals, or +z)."""
    area_mm2: float
    outline: np.ndarray
    """(P, 3) closed polygon around its top."""


@dataclass(frozen=True)
class MeasureResult:
    seams: list[SeamResult]
    junctions: list[JunctionResult]
    findings: list[Finding]
    panels: list[PanelResult]
    point_count: int
    spacing_mm: float
    cell_mm: float
    seconds: dict[str, float]

    @property
    def defects(self) -> list[Finding]:
        return [f for f in self.findings if f.out_of_tolerance]

    @property
    def uncertain(self) -> list[Finding]:
        """Findings too close to their limit for their σ to tell out from within."""
        return [f for f in self.findings if f.uncertain]

    @property
    def panel_area_m2(self) -> float:
        return sum(p.area_mm2 for p in self.panels) / 1e6


def confidence(value: float, limit: float, sigma: float) -> float:
    """Probability that the true value is on the measured side of the limit."""
    z = abs(value - limit) / max(sigma, MIN_SIGMA_MM)
    return 0.5 * (1 + erf(z / sqrt(2)))


def measure(
    cloud: PointCloud,
    config: MeasureConfig | None = None,
    *,
    threads: int = 1,
    progress: Progress | None = None,
) -> MeasureResult:
    """Seams, junctions and surface findings of a stitched panel-assembly cloud, on
    ``threads`` threads (one per core given: see ``services.lib.process`` for the process's
    set-up that lets them scale)."""
    config = config or MeasureConfig()
    report = progress or (lambda fraction, message: None)
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[name] = now - clock
        clock = now

    points, colors, normals = cloud.points, cloud.colors, cloud.normals  # NaNs are skipped
    report(0.02, f"fitting the surface frame to {len(points)} points")
    frame = fit_frame(points, normals)
    if len(points) < 1000:
        raise MeasureError(f"the cloud has {len(points)} points; at least 1000 needed")
    bounds = binning.uv_bounds(points, frame.origin, frame.axes, workers=threads)
    if not np.isfinite(bounds).all():
        raise MeasureError("the cloud has no finite points")
    span_u, span_v = bounds[1] - bounds[0], bounds[3] - bounds[2]
    if span_u * span_v / config.cell_mm**2 > MAX_CELLS:
        raise MeasureError(
            f"the cloud spans {span_u:.0f} × {span_v:.0f} mm: more than {MAX_CELLS:.0e} cells "
            f"of {config.cell_mm:g} mm (far stray points? crop the cloud, or raise cell_mm)"
        )
    raster = rasterize(points, colors, frame, config.cell_mm, bounds, threads)
    binned = int(raster.count.sum())
    if binned < 1000:
        raise MeasureError(f"the cloud has {binned} finite points; at least 1000 needed")
    spacing = point_spacing_mm(raster)
    cell = max(config.cell_mm, 1.5 * spacing)
    if cell > config.cell_mm:
        raster = rasterize(points, colors, frame, cell, bounds, threads)
    lap("raster_s")
    # Segmentation's later passes, then the panels' surfaces and the seams, run on this
    # thread and ``threads`` − 1 in a pool, one per core (the compiled passes, NumPy and
    # SciPy release the GIL for the heavy part): the pool's threads start on the surface
    # while this thread finds the seams and profiles them; a thread that is free takes the
    # next seam or panel. (A pool of ``threads`` had three threads share two cores.)
    helpers = threads - 1
    with ThreadPoolExecutor(helpers) if threads > 1 else nullcontext() as pool:
        # The blocks' colours in L*a*b*, for the surface: on the pool during segmentation.
        lab_work = None
        if config.surface is not None:
            lab_work = start_helping(pool, block_lab, [raster], helpers=helpers)
        report(0.15, f"segmenting panels on a {raster.shape[0]} × {raster.shape[1]} height map")
        panels = segment_panels(
            raster,
            max_slope_deg=config.max_slope_deg,
            min_area_mm2=config.min_panel_area_mm2,
            background_drop_mm=config.background_drop_mm,
            # a map coarsened for a sparse cloud: gaps its rows skip bridge the panels
            bridge_cells=BRIDGE_CELLS if cell > config.cell_mm else 0,
            pool=pool,
            helpers=helpers,
        )
        if panels.count == 0:
            raise MeasureError(
                f"no panel top of at least {config.min_panel_area_mm2:g} mm² found in the cloud"
            )
        lap("panels_s")
        report(0.3, f"{counted(panels.count, 'panel')}: seams, sections and surface")
        surface_work = None
        if lab_work is not None:
            lab = lab_work.finish()[0]
            surface_work = find_surface_defects(raster, panels, config.surface, lab, pool, helpers)
        # A seam's band: half the widest gap, the widest edge, and the edge band.
        sections = config.sections
        max_half_band = (
            config.max_gap_mm / 2 + sections.max_edge_depth_mm / 2 + sections.edge_band_mm
        )
        lines = find_seams(
            raster,
            panels,
            max_half_band_mm=max_half_band,
            min_length_mm=config.min_seam_length_mm,
        )
        lines = [_oriented(line, frame) for line in lines]
        lines, junction_lines = find_junctions(lines, reach_mm=2 * max_half_band + 4.0)
        profiles = _profile_seams(points, raster, lines, config, spacing, pool, helpers, threads)
        shapes = describe_panels(raster, panels)
        surface_parts = surface_work.finish() if surface_work is not None else []
        surface = [finding for part in surface_parts for finding in part]
    located, panel_id = _locate_panels(shapes, frame)
    seam_of_line: dict[int, SeamResult] = {}
    for i, profile in enumerate(profiles):
        if profile is not None and np.isfinite(profile.step_mm).any():
            seam_of_line[i] = _seam_result(len(seam_of_line), profile, frame, config, panel_id)
    seams = list(seam_of_line.values())
    junctions = _junction_results(junction_lines, seam_of_line, frame)
    lap("seams_and_surface_s")
    findings = _seam_findings(seams, junctions, config, spacing)
    findings += [_surface_finding(f, raster, frame, config, panel_id) for f in surface]
    report(
        1.0,
        f"{counted(len(seams), 'seam')}, {counted(len(junctions), 'junction')}, "
        f"{counted(len(findings), 'finding')}",
    )
    return MeasureResult(
        seams, junctions, findings, located, int(len(points)), spacing, cell, seconds
    )


PANEL_COLUMN_MM = 10.0


def _locate_panels(
    shapes: list[PanelShape], frame: SurfaceFrame
) -> tuple[list[PanelResult], dict[int, int]]:
    """The panels in the cloud's frame, numbered by the rule the README states: by their
    centroid's x (centroids within ``PANEL_COLUMN_MM`` of the first of a run count as one
    column), then y, then z — the same geometry gets the same numbers, whatever order the
    height map found them in. Also the map from height-map label to that number."""
    centroids = np.array([frame.to_cloud(s.centroid) for s in shapes]).reshape(-1, 3)
    order = list(np.argsort(centroids[:, 0], kind="stable"))
    columns, column_start = [], None
    for i in order:
        if column_start is None or centroids[i, 0] - column_start > PANEL_COLUMN_MM:
            columns.append([])
            column_start = centroids[i, 0]
        columns[-1].append(i)
    ordered = [
        i for column in columns for i in sorted(column, key=lambda i: tuple(centroids[i, 1:]))
    ]
    located, panel_id = [], {}
    for number, i in enumerate(ordered):
        shape = shapes[i]
        outline = frame.to_cloud(shape.outline)
        normal = frame.direction_to_cloud(shape.normal)
        located.append(
            PanelResult(
                number,
                centroids[i],
                outline.min(axis=0),
                outline.max(axis=0),
                normal / np.linalg.norm(normal),
                shape.area_mm2,
                outline,
            )
        )
        panel_id[shape.label] = number
    return located, panel_id


def _oriented(seam: SeamLine, frame: SurfaceFrame) -> SeamLine:
    """The seam with its panels in the order the README states: b is the panel on the
    side of the cloud axis (x, y or z) that the seam's across direction is closest to —
    so the step (b's top over a's) has the same sign for the same geometry."""
    across = frame.direction_to_cloud(np.array([*seam.across_uv, 0.0]))
    axis = int(np.argmax(np.abs(across)))
    return seam if across[axis] > 0 else seam.reversed()


def warm_up() -> None:
    """Compile (or load from numba's cache) the compiled passes, so that a timing does
    not include it: measure two small synthetic plates with a gap and colours."""
    u, v = np.meshgrid(np.arange(0.0, 121.0, 0.5), np.arange(0.0, 60.0, 0.5), indexing="ij")
    keep = (u < 59.5) | (u > 61.5)
    points = np.stack([u[keep], v[keep], np.zeros(keep.sum())], 1).astype(np.float32)
    colors = np.full(points.shape, 128, np.uint8)
    measure(PointCloud(points=points, colors=colors))
    # and a comparison's distances: a plate's scan against its nominal
    from services.lib.pointcloud.mesh_distance import TriangleMesh, signed_distance

    plate = TriangleMesh(np.array([[0, 0, 0], [121, 0, 0], [121, 60, 0], [0, 60, 0.0]]),
                         np.array([[0, 1, 2], [0, 2, 3]]))  # fmt: skip
    signed_distance(plate, points.astype(np.float64) + [0.0, 0.0, 0.1], workers=2)


BRIDGE_CELLS = 6
"""On a height map coarsened for a sparse cloud, the panels' flat tops are eroded by this
many more cells before they are told apart (``segment_panels``)."""
RESOLVED_SPACINGS = 0.4
"""A seam's sections sample its edges finely enough once their profiles together leave
no stretch wider than this many point spacings near a top's end…"""
MAX_WIDENING = 4.0
"""…else its slabs are widened by up to this factor, once (``_profile_seams``), and the
wider slabs' sections kept where their profiles sample the edges at least this much
more finely:"""
WIDENING_GAIN = 0.75
WIDENED_SPACINGS = 0.25
"""The wider slabs are made thick enough for their profiles' phases to leave stretches of
this many spacings — finer than ``RESOLVED_SPACINGS``: a slab widened just to it drifts
too little in phase to reach it."""


PROBE_SECTIONS = 12
"""A seam's sampling is first learnt from this many of its sections, evenly spread (every
n-th of them: ``_profile_seams``)."""


def _profile_seams(
    points: np.ndarray,
    raster: Raster,
    lines: list[SeamLine],
    config: MeasureConfig,
    spacing_mm: float,
    pool: Executor | None = None,
    helpers: int = 0,
    threads: int = 1,
) -> list[SeamProfile | None]:
    """Each seam's sections. A pass over the points near the seams takes their slabs (on
    ``threads`` threads without a pool, on this thread alone with one: the pool's threads
    are then busy with the panels' surfaces, and a pass split across a third thread on two
    cores ran 2–4 % slower); the seams are then profiled by this thread and, once free,
    by up to ``helpers`` of ``pool``'s threads, the seam with the most points first.

    A seam whose slabs' profiles sample its edges coarsely together (they cross it at
    nearly one phase: a scan grid turned a degree or two to it) is profiled from wider
    slabs, whose profiles drift further in phase (``RESOLVED_SPACINGS``), taken by a
    second pass. Which seams, and how much wider, is learnt from ``PROBE_SECTIONS`` of
    each seam's sections at the usual width: a whole profile at the usual width, made and
    then replaced by the wider one, cost a 0.1 mm cloud scanned 2° to its seams a fifth
    of its time. A wider profile that samples the edges no more finely than the probe did
    (``WIDENING_GAIN``) gives way to the usual one."""
    if not lines:
        return []
    sections = config.sections
    margin = max(s.half_band_mm for s in lines) + sections.end_margin_mm
    base_mm = slab_width_mm(sections, spacing_mm)
    workers = 1 if pool is not None else threads

    def ranges_for(slab_mm: float) -> list[tuple[float, int]]:
        """Sections clear of the seams' ends by the margin and by what a slab thicker
        than ``slab_mm`` reaches further along (into a crossing seam's gap)."""
        extra = max(slab_mm - sections.slab_mm, 0.0) / 2
        return [section_range(s, sections, end_margin_mm=margin + extra) for s in lines]

    def slabs_for(seams: list[int], widths: list[float]) -> list[np.ndarray]:
        """The ``seams``' slabs ``widths`` thick, from one pass over the points."""
        if not seams:
            return []
        ranges = [ranges_for(width)[i] for i, width in zip(seams, widths, strict=True)]
        lines_of = [lines[i] for i in seams]
        return _slabs(
            points, raster, lines_of, ranges, widths, base_mm, sections, spacing_mm, workers
        )

    def profiled(i: int, slab: np.ndarray, width: float, stride: int = 1) -> SeamProfile | None:
        """Seam i's every ``stride``-th section from its ``slab`` rows, ``width`` thick."""
        first, count = ranges_for(width)[i]
        if count <= 0:  # a seam too short for a section clear of its ends
            return None
        if stride > 1:
            slab = slab[:, slab[0] % stride == 0]
            slab[0] //= stride
        pitched = replace(sections, pitch_mm=sections.pitch_mm * stride)
        return profile_seam(slab, lines[i], pitched, first, -(-count // stride), spacing_mm)

    def profile_all(
        seams: list[int],
        slabs: list[np.ndarray],
        widths: list[float],
        strides: list[int] | None = None,
    ) -> list[SeamProfile | None]:
        """``profiled`` of each of ``seams``, the largest slab first."""
        return helping_map(
            pool,
            profiled,
            seams,
            slabs,
            widths,
            strides or [1] * len(seams),
            sizes=[slab.shape[1] for slab in slabs],
            helpers=helpers,
        )

    every = list(range(len(lines)))
    usual = [base_mm] * len(lines)
    slabs = slabs_for(every, usual)
    if sections.min_profiles <= 0:  # the gauge: one scan line, as it is
        return profile_all(every, slabs, usual)
    strides = [max(count // PROBE_SECTIONS, 1) for _, count in ranges_for(base_mm)]
    probes = profile_all(every, slabs, usual, strides)
    widths = [base_mm * _widening(probe, spacing_mm) for probe in probes]
    wide = [i for i in every if widths[i] > base_mm]
    # A probe of every section at the usual width is already the seam's profile.
    again = [i for i in every if widths[i] == base_mm and strides[i] > 1]
    wide_slabs = slabs_for(wide, [widths[i] for i in wide])
    profiles = list(probes)
    finals = profile_all(
        wide + again, wide_slabs + [slabs[i] for i in again], [widths[i] for i in wide + again]
    )
    for i, final in zip(wide + again, finals, strict=True):
        profiles[i] = final
    # A wider profile no finer than its probe gives way to the usual one.
    back = [
        i
        for i in wide
        if not (
            profiles[i] is not None
            and profiles[i].sampling_mm < WIDENING_GAIN * probes[i].sampling_mm
        )
    ]
    redone = profile_all(back, [slabs[i] for i in back], [base_mm] * len(back))
    for i, profile in zip(back, redone, strict=True):
        profiles[i] = profile
    return profiles


def _widening(probe: SeamProfile | None, spacing_mm: float) -> float:
    """How many times the usual thickness a seam's slabs are made, from its ``probe``: 1
    where its profiles already sample its edges finely (``RESOLVED_SPACINGS``) or a
    thicker slab could not gain (``_widening_gains``); else as thick as should leave
    stretches of ``WIDENED_SPACINGS``, up to ``MAX_WIDENING``."""
    if probe is None or not probe.sampling_mm > RESOLVED_SPACINGS * spacing_mm:
        return 1.0
    factor = min(probe.sampling_mm / (WIDENED_SPACINGS * spacing_mm), MAX_WIDENING)
    return factor if _widening_gains(probe, factor) else 1.0


def _widening_gains(profile: SeamProfile, factor: float) -> bool:
    """Whether slabs ``factor`` times thicker could sample the seam's edges at least
    ``WIDENING_GAIN`` as coarsely. The profiles' phase drifts along the seam at a steady
    rate (the scan grid's small angle to it), so the stretches they leave shrink linearly
    with the slab's thickness T: by s(T/2) − s(T) from the slab's middle half to the whole
    of it (``sampling_mid_mm``), and by 2(factor − 1) times that more at factor · T. Where
    the middle half samples as finely as the whole (every profile crosses the edges at one
    phase: rows exactly along the seam, or at 45° on a square grid), a thicker slab cannot
    gain and is not profiled. Unknown drift (NaN): it is tried."""
    base, mid = profile.sampling_mm, profile.sampling_mid_mm
    if not np.isfinite(mid):
        return True
    predicted = base - 2 * (factor - 1) * max(mid - base, 0.0)
    return predicted < WIDENING_GAIN * base


def _slabs(
    points: np.ndarray,
    raster: Raster,
    lines: list[SeamLine],
    ranges: list[tuple[float, int]],
    slabs_mm: list[float],
    dense_mm: float,
    sections: SectionConfig,
    spacing_mm: float,
    workers: int,
) -> list[np.ndarray]:
    """Each of ``lines``' section slabs ``slabs_mm`` thick (``ranges``: each seam's first
    section and how many), as (4, M) rows (``binning.seam_slabs``), from one pass on
    ``workers`` threads. Slabs thicker than ``dense_mm`` hold every point only that close
    to their plane or near the edges (``edge_reach_mm``); beyond both, the tops — which a
    slab ``dense_mm`` thick samples finely enough to fit — are thinned to that slab's
    density (a 4 mm slab's profiles then cost little more than a 1 mm one's where they
    would add nothing: away from the edges)."""
    pieces = binning.seam_slabs(
        points,
        raster.frame.origin,
        raster.frame.axes,
        raster.grid,
        raster.count,
        raster.chunk_uv,
        np.array([[*s.centre_uv, *s.direction_uv, s.start_mm, s.end_mm] for s in lines]),
        np.array(
            [
                [
                    first,
                    sections.pitch_mm,
                    max(count, 0),
                    slab_mm / 2,
                    reach_mm(s, sections),
                    dense_mm / 2,
                    edge_reach_mm(s, spacing_mm),
                    max(round(slab_mm / dense_mm), 1),
                ]
                for s, (first, count), slab_mm in zip(lines, ranges, slabs_mm, strict=True)
            ]
        ),
        workers,
    )
    return [np.concatenate(seam, 1) for seam in pieces]


def _seam_result(
    index: int,
    profile: SeamProfile,
    frame: SurfaceFrame,
    config: MeasureConfig,
    panel_id: dict[int, int],
) -> SeamResult:
    seam = profile.seam
    measured = np.isfinite(profile.gap_mm)
    along, gap = profile.along_mm[measured], profile.gap_mm[measured]
    steps = profile.step_mm[np.isfinite(profile.step_mm)]
    unmeasured = _seam_unmeasured(profile, config)
    gap_stats = ends = parallelism = None
    gap_sigma = MIN_SIGMA_MM
    if unmeasured is None:
        own = float(np.median(profile.gap_sigma_mm[measured]))
        if len(gap) >= 3:
            slope, offset = np.polyfit(along, gap, 1)
            scatter = float(np.std(gap - (slope * along + offset), ddof=2))
        else:
            slope, offset, scatter = 0.0, float(gap.mean()), 0.0
        ends = (float(slope * seam.start_mm + offset), float(slope * seam.end_mm + offset))
        gap_stats = Stats(min=float(gap.min()), mean=float(gap.mean()), max=float(gap.max()))
        parallelism = abs(ends[1] - ends[0])
        gap_sigma = max(scatter, own, MIN_SIGMA_MM)
    height = float(np.nanmean(profile.at_local[:, 2]))
    at_local = profile.at_local.copy()
    at_local[:, 2] = np.where(np.isfinite(at_local[:, 2]), at_local[:, 2], height)
    start_end = seam.point_uv(np.array([seam.start_mm, seam.end_mm]))
    start_end = frame.to_cloud(np.column_stack([start_end, [height, height]]))
    normal = frame.direction_to_cloud(np.nanmean(profile.normal_local, axis=0))
    return SeamResult(
        id=index,
        panels=(panel_id[seam.panels[0]], panel_id[seam.panels[1]]),
        start=start_end[0],
        end=start_end[1],
        length_mm=seam.length_mm,
        gap_mm=gap_stats,
        step_mm=Stats(min=float(steps.min()), mean=float(steps.mean()), max=float(steps.max())),
        gap_at_ends_mm=ends,
        parallelism_mm=parallelism,
        gap_sigma_mm=gap_sigma,
        step_sigma_mm=max(float(np.std(steps)), MIN_SIGMA_MM),
        edges=profile.edges,
        noise_mm=profile.noise_mm,
        normal=normal / np.linalg.norm(normal),
        sections_at=frame.to_cloud(at_local),
        sections_gap_mm=profile.gap_mm,
        sections_step_mm=profile.step_mm,
        sections_gap_sigma_mm=profile.gap_sigma_mm,
        sections_models=profile.models,
        sections_residual_mm=profile.residual_mm,
        sections_unmeasured=profile.unmeasured,
        unmeasured=unmeasured,
        edge_sampling_mm=profile.sampling_mm,
    )


def _seam_unmeasured(profile: SeamProfile, config: MeasureConfig) -> str | None:
    """Why a seam yields no gap, parallelism or mismatch: fewer measured sections than
    ``min_measured_share`` of them (or than three)."""
    total = len(profile.gap_mm)
    measured = int(np.isfinite(profile.gap_mm).sum())
    if measured >= max(3, config.min_measured_share * total):
        return None
    reasons = [r for r in profile.unmeasured if r is not None]
    kinds = [re.sub(r"[−-]?\d[\d.]*", "#", r) for r in reasons]
    common = reasons[kinds.index(max(set(kinds), key=kinds.count))] if reasons else "no gap"
    return f"only {measured} of {total} sections measured (most often: {common})"


def _junction_results(
    junctions: list[Junction],
    seam_of_line: dict[int, SeamResult],
    frame: SurfaceFrame,
) -> list[JunctionResult]:
    """Mismatch where at least three measured seams meet."""
    results = []
    for junction in junctions:
        ids, gaps, heights, sigmas = [], [], [], []
        for line_index, end in zip(junction.seams, junction.ends, strict=True):
            seam = seam_of_line.get(line_index)
            if seam is None or seam.gap_at_ends_mm is None:
                continue
            ids.append(seam.id)
            gaps.append(seam.gap_at_ends_mm[end])
            sigmas.append(seam.gap_sigma_mm)
            heights.append(frame.to_local(seam.start if end == 0 else seam.end)[2])
        if len(ids) < 3:
            continue
        at = frame.to_cloud(np.append(junction.at_uv, np.mean(heights)))
        results.append(
            JunctionResult(
                len(results),
                at,
                tuple(ids),
                tuple(gaps),
                float(max(gaps) - min(gaps)),
                float(np.sqrt(2) * max(sigmas)),
            )
        )
    return results


def _judged(
    value: float,
    limit: float,
    sigma_mm: float,
    *,
    above: bool,
    spacing_mm: float,
    measurements: FindingMeasurements,
    one_phase: bool = False,
) -> tuple[str, str, float, FindingMeasurements]:
    """(severity, tolerance state, confidence, measurements with the 1σ, the state and,
    for an uncertain finding, the advice) of a seam's or junction's measurement;
    ``one_phase``: its edges were sampled at one place by every profile (kept, for the
    advice when the tolerances change)."""
    sigma_mm = round(sigma_mm, 4)  # as stored, so the advice quotes the same σ
    state = tolerance_state(value, limit, sigma_mm, above=above)
    uncertain = state == "uncertain"
    return (
        severity(value, limit, above=above),
        state,
        confidence(value, limit, sigma_mm),
        revised(
            measurements,
            sigma_mm=sigma_mm,
            tolerance_state=state,
            spacing_mm=round(spacing_mm, 4),
            one_phase=one_phase or None,
            advice=advice(value, limit, sigma_mm, spacing_mm, one_phase) if uncertain else None,
        ),
    )


ONE_PHASE_SAMPLING = (0.9, 1.5)
"""A seam whose pooled profiles leave stretches of this many (measured) spacings near the
tops' ends was sampled at one place by all of them: its advice says to turn the scan. The
measured spacing runs up to a fifth under the grid's pitch where scans overlap; stretches
much wider than a spacing are missing points (dropout), not one phase."""


def _gap_findings(
    seam: SeamResult,
    config: MeasureConfig,
    source: dict,
    profile: SeamMeasurements,
    spacing_mm: float,
) -> list[Finding]:
    """The gap (worst running median of the measured sections, or the gap line at the
    seam's ends) and the parallelism of a measured seam, each with its 1σ and judged by
    ``contract.tolerances.judge``'s rule."""
    t = config.tolerances
    measured = seam.measured
    low, high = ONE_PHASE_SAMPLING
    one_phase = bool(low * spacing_mm <= seam.edge_sampling_mm <= high * spacing_mm)
    # The gap line at the seam's ends counts too: sections stop short of them.
    medians = running_median(seam.sections_gap_mm[measured], config.sections.decision_sections)
    gaps = np.concatenate([medians, seam.gap_at_ends_mm])
    places = np.concatenate([seam.sections_at[measured], [seam.start, seam.end]])
    sigmas = np.concatenate([seam.sections_gap_sigma_mm[measured], [0.0, 0.0]])
    narrowest, widest = int(np.argmin(gaps)), int(np.argmax(gaps))
    sigma = max(seam.gap_sigma_mm, float(sigmas[narrowest]), float(sigmas[widest]))
    gap_range = (round(float(gaps[narrowest]), 4), round(float(gaps[widest]), 4))
    judged = judge("gap", gaps[widest], t, gap_range, sigma)  # which end, against which limit
    above = judged.value == gap_range[1] and judged.limit == t.gap_max_mm
    worst = widest if above else narrowest
    outside = gaps > t.gap_max_mm if above else gaps < t.gap_min_mm
    severity_, state, confidence_, measurements = _judged(
        float(gaps[worst]),
        judged.limit,
        sigma,
        above=above,
        spacing_mm=spacing_mm,
        one_phase=one_phase,
        # what it was judged on, and where: a change of tolerances judges it again
        # (contract.tolerances.judge) and moves it to the end of the range it is judged by
        measurements=revised(
            profile,
            gap_range_mm=gap_range,
            gap_range_at_mm=(
                tuple(round(float(v), 4) for v in places[narrowest]),
                tuple(round(float(v), 4) for v in places[widest]),
            ),
        ),
    )
    gap = Finding(
        "gap",
        float(gaps[worst]),
        "mm",
        judged.limit,
        places[worst],
        seam.normal,
        float(max(outside[:-2].sum(), 1) * config.sections.pitch_mm),
        severity_,
        confidence_,
        source,
        measurements,
        sigma,
        state,
    )
    parallelism_sigma = float(np.sqrt(2) * seam.gap_sigma_mm)
    severity_, state, confidence_, measurements = _judged(
        seam.parallelism_mm,
        t.parallelism_max_mm,
        parallelism_sigma,
        above=True,
        spacing_mm=spacing_mm,
        measurements=profile,
        one_phase=one_phase,
    )
    parallelism = Finding(
        "parallelism",
        seam.parallelism_mm,
        "mm",
        t.parallelism_max_mm,
        (seam.start + seam.end) / 2,
        seam.normal,
        seam.length_mm,
        severity_,
        confidence_,
        source,
        measurements,
        parallelism_sigma,
        state,
    )
    return [gap, parallelism]


def running_median(values: np.ndarray, window: int) -> np.ndarray:
    """Median over ``window`` neighbouring sections: what a seam is judged on, so that one
    section's noise cannot tip it over a limit (a deviation longer than the window stays)."""
    if window <= 1 or len(values) < window:
        return values
    return ndimage.median_filter(values, size=window, mode="nearest")


def _seam_findings(
    seams: list[SeamResult],
    junctions: list[JunctionResult],
    config: MeasureConfig,
    spacing_mm: float,
) -> list[Finding]:
    """Gap, step and parallelism of every seam and mismatch of every junction, judged on
    measured sections only: an unmeasured section or seam yields no finding."""
    t = config.tolerances
    findings = []
    window, pitch = config.sections.decision_sections, config.sections.pitch_mm
    for seam in seams:
        source = {"seam": seam.id, "panels": list(seam.panels)}
        profile = SeamMeasurements(
            gap_mm=seam.gap_mm,
            step_mm=seam.step_mm,
            parallelism_mm=seam.parallelism_mm,
            length_mm=seam.length_mm,
            unmeasured_sections=int((~seam.measured).sum()),
        )
        on_seam = []
        if seam.unmeasured is None:
            on_seam += _gap_findings(seam, config, source, profile, spacing_mm)
        has_step = np.isfinite(seam.sections_step_mm)
        if has_step.sum() >= 3:
            steps = running_median(seam.sections_step_mm[has_step], window)
            worst = int(np.argmax(np.abs(steps)))
            value = float(steps[worst])
            severity_, state, confidence_, measurements = _judged(
                abs(value),
                t.step_max_mm,
                seam.step_sigma_mm,
                above=True,
                spacing_mm=spacing_mm,
                measurements=profile,
            )
            on_seam.append(
                Finding(
                    "step",
                    value,
                    "mm",
                    t.step_max_mm,
                    seam.sections_at[has_step][worst],
                    seam.normal,
                    float(max((np.abs(steps) > t.step_max_mm).sum(), 1) * pitch),
                    severity_,
                    confidence_,
                    source,
                    measurements,
                    seam.step_sigma_mm,
                    state,
                )
            )
        findings += [_along_seam(f, seam) for f in on_seam]
    normal_of = {s.id: s.normal for s in seams}
    for junction in junctions:
        normal = np.mean([normal_of[i] for i in junction.seams], axis=0)
        severity_, state, confidence_, measurements = _judged(
            junction.mismatch_mm,
            t.mismatch_max_mm,
            junction.mismatch_sigma_mm,
            above=True,
            spacing_mm=spacing_mm,
            measurements=JunctionMeasurements(gaps_mm=list(junction.gaps_mm)),
        )
        findings.append(
            Finding(
                "mismatch",
                junction.mismatch_mm,
                "mm",
                t.mismatch_max_mm,
                junction.at,
                normal / np.linalg.norm(normal),
                2 * config.max_gap_mm,
                severity_,
                confidence_,
                {"junction": junction.id, "seams": list(junction.seams)},
                measurements,
                junction.mismatch_sigma_mm,
                state,
            )
        )
    return findings


def _along_seam(finding: Finding, seam: SeamResult) -> Finding:
    """The finding with where it lies along its seam (mm from the seam's start) and the
    seam's ends (mm): what a later measurement's finding is matched by."""
    direction = seam.end - seam.start
    along_mm = float(np.dot(finding.location - seam.start, direction) / np.linalg.norm(direction))
    seam_mm = (tuple(np.round(seam.start, 2).tolist()), tuple(np.round(seam.end, 2).tolist()))
    return replace(
        finding,
        measurements=revised(finding.measurements, along_mm=round(along_mm, 1), seam_mm=seam_mm),
    )


def _surface_finding(
    finding: SurfaceFinding,
    raster: Raster,
    frame: SurfaceFrame,
    config: MeasureConfig,
    panel_id: dict[int, int],
) -> Finding:
    limit = upper_limit(config.tolerances, finding.type)
    unit = "delta_e" if finding.type == "color" else "mm"
    point, normal = _surface_point(raster, finding.at_uv)
    return Finding(
        finding.type,
        finding.value,
        unit,
        limit,
        frame.to_cloud(point),
        frame.direction_to_cloud(normal),
        finding.extent_mm,
        severity(finding.value, limit, above=True),
        finding.confidence,
        {"panel": panel_id[finding.panel]},
        finding.measurements,
    )


def _surface_point(
    raster: Raster, uv: np.ndarray, radius_mm: float = 5.0
) -> tuple[np.ndarray, np.ndarray]:
    """(u, v, w) on the plane fitted to the height map within ``radius_mm`` of ``uv``, and
    that plane's unit normal (towards +w)."""
    span = int(np.ceil(radius_mm / raster.cell_mm))
    row, col, _ = raster.cell_at(uv)
    row0, col0 = max(int(row) - span, 0), max(int(col) - span, 0)
    window = raster.height[row0 : int(row) + span + 1, col0 : int(col) + span + 1]
    rows, cols = np.nonzero(np.isfinite(window))
    centres = raster.centres_uv(rows + row0, cols + col0) - uv
    design = np.column_stack([np.ones(len(rows)), centres])
    heights = window[rows, cols].astype(np.float64)
    (w0, du, dv), *_ = np.linalg.lstsq(design, heights, rcond=None)
    normal = np.array([-du, -dv, 1.0])
    return np.array([uv[0], uv[1], w0]), normal / np.linalg.norm(normal)
