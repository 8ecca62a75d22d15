"""A scan's signed deviation from its nominal, judged against surface-profile bands: per
region of the nominal its statistics and how much of it the scan covered, and the areas out
of their band as findings.

A finding is a connected area of points beyond the band on one side (above or below), in
one region: points in touching cells of ``LINK_SPACINGS`` point spacings belong
together. An area smaller than ``MIN_POINTS`` points is not reported: a stray point, or the noise of a surface lying at
the band's edge. Its value is its peak deviation, signed, where that lies — each point's
deviation taken as the median of its nine nearest in the area, so that a stray point
inside it is no peak; its area is its points' share of the cloud's area (spacing² a
point); its mean is over its points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from contract.tolerances import Limits, judge
from services.lib.pointcloud.mesh_distance import MeshDistance, TriangleMesh, face_normals

LINK_SPACINGS = 2.0
NEIGHBOUR_CELLS = float(np.sqrt(3))
"""Cells touching at a face, an edge or a corner are neighbours. Measured both ways:
against a ±0.25 mm band, face neighbours only cut the false findings of a 2 mm, 0.1 mm-noise
scan from 6.8 to 1.7 per m², but split a 0.3 mm bow's rim (where it barely leaves the
band) into 27–29 findings instead of 8 on a 0.5 mm scan; the recall was the same."""
MIN_POINTS = 12
PEAK_NEIGHBOURS = 9
COVER_SPACINGS = 3.0
"""A place on the nominal is covered when a scan point lies within this many spacings."""
COVER_SAMPLES = 400_000
"""Points spread over the nominal to measure its coverage."""
STRAY_MM = 25.0
"""Points farther than this from the nominal are strays (not the part): not judged. So is
a point beyond twice its band that is in no area (no neighbour out of the band with it):
a surface is continuous, a stray is alone. Neither counts in a region's statistics."""


@dataclass(frozen=True)
class RegionStats:
    name: str
    points: int
    mean_mm: float | None
    sigma_mm: float | None
    min_mm: float | None
    max_mm: float | None
    within_share: float | None
    coverage_share: float
    band_mm: tuple[float, float]

    def document(self) -> dict:
        def mm(value: float | None) -> float | None:
            return None if value is None else round(value, 4)

        return {
            "region": self.name,
            "points": self.points,
            "mean_mm": mm(self.mean_mm),
            "sigma_mm": mm(self.sigma_mm),
            "min_mm": mm(self.min_mm),
            "max_mm": mm(self.max_mm),
            "within_share": None if self.within_share is None else round(self.within_share, 4),
            "coverage_share": round(self.coverage_share, 4),
            "band_mm": list(self.band_mm),
        }


@dataclass(frozen=True)
class DeviationFinding:
    region: str
    value_mm: float
    """Peak signed deviation."""
    at_mm: np.ndarray
    """Where the peak lies (the nominal's frame)."""
    normal: np.ndarray
    """The nominal's normal there."""
    mean_mm: float
    area_mm2: float
    points: int
    extent_mm: float
    """The diagonal of its box."""
    limit_mm: float
    band_mm: tuple[float, float]
    severity: str
    state: str

    def document(self) -> dict:
        return {
            "type": "deviation",
            "region": self.region,
            "value": round(self.value_mm, 4),
            "unit": "mm",
            "tolerance": self.limit_mm,
            "band_mm": list(self.band_mm),
            "location": np.round(self.at_mm, 3).tolist(),
            "normal": np.round(self.normal, 5).tolist(),
            "mean_mm": round(self.mean_mm, 4),
            "area_mm2": round(self.area_mm2, 2),
            "points": self.points,
            "extent_mm": round(self.extent_mm, 2),
            "severity": self.severity,
            "tolerance_state": self.state,
        }


@dataclass(frozen=True)
class Deviation:
    deviation_mm: np.ndarray
    """(N,) each point's signed distance to the nominal; NaN for strays (``STRAY_MM``)."""
    region_of_point: np.ndarray
    """(N,) index into ``regions`` of the face nearest each point."""
    regions: tuple[RegionStats, ...]
    findings: tuple[DeviationFinding, ...]
    spacing_mm: float
    strays: int


def judge_deviation(
    points_mm: np.ndarray,
    distance: MeshDistance,
    mesh: TriangleMesh,
    region_of_face: np.ndarray,
    region_names: tuple[str, ...],
    limits: Limits,
    *,
    sigma_mm: float | None = None,
) -> Deviation:
    """The deviation of ``points_mm`` (aligned, the nominal's frame) found as ``distance``,
    per region and as findings against ``limits``' profile bands; a finding's peak within
    2 ``sigma_mm`` (the scan's noise) of its band is uncertain."""
    deviation = distance.distance_mm.copy()
    stray = np.abs(deviation) > STRAY_MM
    deviation[stray] = np.nan
    region = region_of_face[distance.face]
    spacing = point_spacing(points_mm[~stray])
    bands = np.array([limits.profile_band(name) for name in region_names]).reshape(-1, 2)
    low, high = bands[region, 0], bands[region, 1]
    normals = face_normals(mesh)[distance.face]
    findings, in_area = [], np.zeros(len(deviation), dtype=bool)
    for out in (~stray & (deviation > high), ~stray & (deviation < low)):
        for members in connected_areas(points_mm, out, region, spacing):
            in_area[members] = True
            name = region_names[region[members[0]]]
            findings.append(
                _finding(points_mm, deviation, members, name, normals, limits, spacing, sigma_mm)
            )
    # a point beyond twice its band that no neighbour follows is no surface: a stray too
    reach = 2 * np.maximum(np.abs(low), np.abs(high))
    stray |= ~in_area & (np.abs(np.nan_to_num(deviation)) > reach)
    deviation[stray] = np.nan
    coverage = _coverage(mesh, region_of_face, len(region_names), points_mm[~stray], spacing)
    stats = tuple(
        _region_stats(name, deviation[~stray & (region == r)], low_high, coverage[r])
        for r, (name, low_high) in enumerate(zip(region_names, map(tuple, bands), strict=True))
    )
    findings.sort(key=lambda f: -abs(f.value_mm))
    return Deviation(deviation, region, stats, tuple(findings), spacing, int(stray.sum()))


def point_spacing(points_mm: np.ndarray, sample: int = 20_000) -> float:
    """The spacing of points sampling a surface: 1/√density, from the median distance to
    the 8th neighbour (d₈ ≈ √(8 / (π ρ))), which overlapping scans' near-duplicates do not
    shrink as they do the nearest one."""
    if len(points_mm) < 9:
        return 1.0
    step = max(1, len(points_mm) // sample)
    distance, _ = cKDTree(points_mm).query(points_mm[::step], k=9)
    return float(max(np.median(distance[:, 8]) * np.sqrt(np.pi / 8), 1e-3))


def _region_stats(name: str, values: np.ndarray, band: tuple[float, float],
                  coverage: float) -> RegionStats:  # fmt: skip
    if len(values) == 0:
        return RegionStats(name, 0, None, None, None, None, None, coverage, band)
    within = (values >= band[0]) & (values <= band[1])
    return RegionStats(
        name,
        len(values),
        float(values.mean()),
        float(values.std()),
        float(values.min()),
        float(values.max()),
        float(within.mean()),
        coverage,
        band,
    )


def connected_areas(points_mm: np.ndarray, out: np.ndarray, region: np.ndarray,
           spacing: float) -> list[np.ndarray]:  # fmt: skip
    """The connected areas of the ``out`` points (each a region's), as index arrays."""
    chosen = np.flatnonzero(out)
    if len(chosen) < MIN_POINTS:
        return []
    cell = LINK_SPACINGS * spacing
    keys = np.floor(points_mm[chosen] / cell).astype(np.int64)
    keys = np.column_stack([keys, region[chosen]])
    cells, cell_of_point = np.unique(keys, axis=0, return_inverse=True)
    cell_of_point = cell_of_point.ravel()
    # touching cells (NEIGHBOUR_CELLS) in the same region are one area
    tree = cKDTree(cells[:, :3].astype(float))
    pairs = tree.query_pairs(NEIGHBOUR_CELLS + 1e-6, output_type="ndarray")
    pairs = pairs[cells[pairs[:, 0], 3] == cells[pairs[:, 1], 3]]
    graph = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(cells), len(cells))
    )
    _, label_of_cell = connected_components(graph, directed=False)
    label = label_of_cell[cell_of_point]
    order = np.argsort(label, kind="stable")
    bounds = np.flatnonzero(np.diff(label[order])) + 1
    return [chosen[group] for group in np.split(order, bounds) if len(group) >= MIN_POINTS]


def _finding(points_mm: np.ndarray, deviation: np.ndarray, members: np.ndarray, region: str,
             normals: np.ndarray, limits: Limits, spacing: float,
             sigma_mm: float | None) -> DeviationFinding:  # fmt: skip
    values = _local_median(points_mm[members], deviation[members])
    peak = members[int(np.argmax(np.abs(values)))]
    value = float(values[members == peak][0])
    judged = judge("deviation", value, limits, sigma_mm=sigma_mm, region=region)
    assert judged is not None
    box = points_mm[members].max(axis=0) - points_mm[members].min(axis=0)
    return DeviationFinding(
        region=region,
        value_mm=value,
        at_mm=points_mm[peak],
        normal=normals[peak],
        mean_mm=float(values.mean()),
        area_mm2=float(len(members) * spacing**2),
        points=len(members),
        extent_mm=float(np.linalg.norm(box)),
        limit_mm=judged.limit,
        band_mm=limits.profile_band(region),
        severity=judged.severity,
        state=judged.state,
    )


def _local_median(points_mm: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each point's deviation as the median of its ``PEAK_NEIGHBOURS`` nearest points' in
    its area (itself among them): a stray point, or the noise of one, does not make a
    peak."""
    k = min(PEAK_NEIGHBOURS, len(values))
    _, nearest = cKDTree(points_mm).query(points_mm, k=k)
    return np.median(values[nearest.reshape(len(values), k)], axis=1)


def _coverage(mesh: TriangleMesh, region_of_face: np.ndarray, regions: int,
              points_mm: np.ndarray, spacing: float) -> np.ndarray:  # fmt: skip
    """Per region, the share of its area within ``COVER_SPACINGS`` spacings of a point."""
    corners = np.asarray(mesh.vertices_mm, dtype=np.float64)[mesh.faces]
    area = 0.5 * np.linalg.norm(
        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
    )
    rng = np.random.default_rng(0)
    face = rng.choice(len(area), COVER_SAMPLES, p=area / area.sum())
    r1, r2 = rng.random(COVER_SAMPLES), rng.random(COVER_SAMPLES)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    c = corners[face]
    samples = c[:, 0] + r1[:, None] * (c[:, 1] - c[:, 0]) + r2[:, None] * (c[:, 2] - c[:, 0])
    if len(points_mm) == 0:
        return np.zeros(regions)
    reach, _ = cKDTree(points_mm).query(samples, distance_upper_bound=COVER_SPACINGS * spacing)
    covered = np.isfinite(reach)
    weights = np.bincount(region_of_face[face], minlength=regions).astype(float)
    hits = np.bincount(region_of_face[face], weights=covered, minlength=regions)
    return np.divide(hits, weights, out=np.zeros(regions), where=weights > 0)
