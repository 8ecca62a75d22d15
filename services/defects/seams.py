"""Seams between adjacent panels and the junctions where several meet, on the height map.

The band between panel tops is split by a Voronoi partition (each empty cell goes to the
nearest top); where the regions of two panels touch inside the band runs their seam's
centre line. Junctions are where the ends of three or more seams come together.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from services.defects.panels import Panels
from services.defects.raster import Raster


@dataclass(frozen=True)
class SeamLine:
    """A straight seam in the (u, v) plane between panel labels ``panels`` = (a, b), b on
    the +across side (across = direction turned +90°)."""

    panels: tuple[int, int]
    centre_uv: np.ndarray
    direction_uv: np.ndarray
    start_mm: float
    end_mm: float
    """Extent along ``direction_uv`` from ``centre_uv``."""
    half_band_mm: float
    """Half the width of the band without panel top around the centre line."""

    @property
    def across_uv(self) -> np.ndarray:
        return np.array([-self.direction_uv[1], self.direction_uv[0]])

    def point_uv(self, along_mm: np.ndarray) -> np.ndarray:
        return self.centre_uv + np.multiply.outer(along_mm, self.direction_uv)

    @property
    def length_mm(self) -> float:
        return self.end_mm - self.start_mm

    def reversed(self) -> SeamLine:
        """The same line run the other way: its panels swap sides."""
        return replace(
            self,
            panels=(self.panels[1], self.panels[0]),
            direction_uv=-self.direction_uv,
            start_mm=-self.end_mm,
            end_mm=-self.start_mm,
        )


@dataclass(frozen=True)
class Junction:
    at_uv: np.ndarray
    seams: tuple[int, ...]
    """Indices into the seam list."""
    ends: tuple[int, ...]
    """For each seam, 0 if the junction is at its start, 1 at its end."""


def find_seams(
    raster: Raster,
    panels: Panels,
    *,
    max_half_band_mm: float,
    min_length_mm: float,
    coarse_mm: float = 1.0,
) -> list[SeamLine]:
    """Every pair of panels whose Voronoi regions share a boundary at least
    ``min_length_mm`` long within ``max_half_band_mm`` of both tops."""
    stride = max(1, int(round(coarse_mm / raster.cell_mm)))
    rows = np.arange(stride // 2, raster.shape[0], stride)
    cols = np.arange(stride // 2, raster.shape[1], stride)
    coarse = panels.labels[np.ix_(rows, cols)]
    distance, (near_r, near_c) = ndimage.distance_transform_edt(coarse == 0, return_indices=True)
    nearest = coarse[near_r, near_c]
    distance_mm = distance * stride * raster.cell_mm
    centroids = _centroids_uv(raster, panels)
    seams = []
    first, second, mid, half = [], [], [], []  # per boundary step between two cells
    for axis in (0, 1):
        a = nearest[:-1, :] if axis == 0 else nearest[:, :-1]
        b = nearest[1:, :] if axis == 0 else nearest[:, 1:]
        da = distance_mm[:-1, :] if axis == 0 else distance_mm[:, :-1]
        db = distance_mm[1:, :] if axis == 0 else distance_mm[:, 1:]
        boundary = (a != b) & (a > 0) & (b > 0) & (np.maximum(da, db) <= max_half_band_mm)
        i, j = np.nonzero(boundary)
        ca = raster.centres_uv(rows[i], cols[j])
        cb = raster.centres_uv(rows[i + 1 - axis], cols[j + axis])
        first.append(a[boundary])
        second.append(b[boundary])
        mid.append((ca + cb) / 2)
        half.append(np.minimum(da, db)[boundary])
    first, second = np.concatenate(first), np.concatenate(second)
    mid, half = np.concatenate(mid), np.concatenate(half)
    low, high = np.minimum(first, second), np.maximum(first, second)
    for pair in np.unique(low * (panels.count + 1) + high):
        a, b = divmod(int(pair), panels.count + 1)
        on = (low == a) & (high == b)
        for run in _straight_runs(mid[on]):
            points = mid[on][run]
            if len(points) * coarse_mm < min_length_mm:
                continue
            centre, direction = _line(points)
            across = np.array([-direction[1], direction[0]])
            if (centroids[a] - centre) @ across > 0:  # panel a on the +across side
                direction = -direction
            along = (points - centre) @ direction
            seam = SeamLine(
                (a, b),
                centre,
                direction,
                float(along.min()),
                float(along.max()),
                float(np.median(half[on][run])),
            )
            seams.append(_trim_to_tops(raster, panels.labels, seam))
    return [s for s in seams if s.length_mm >= min_length_mm]


STRAIGHT_MM = 2.0
"""A boundary between two panels whose points stray further than this from one line is
bent — two seams, where the panels on one side of a corner were not told apart (a coarse
scan across a narrow gap merges them) — and is split into straight runs…"""
BEND_DEG = 20.0
"""…if they turn by more than this: a jog along one seam is no corner."""


def _line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre, unit direction) of the line fitted to (N, 2) ``points``."""
    centre = points.mean(0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    return centre, vt[0]


def _straight_runs(points: np.ndarray) -> list[np.ndarray]:
    """Boolean masks of (N, 2) boundary ``points``: all of them, if they lie along one
    line (95 % within ``STRAIGHT_MM``); else two runs, one each side of the bend: split
    along the line's own direction (an L's arms lie either side of its middle), then each
    point given to the nearer of the two lines fitted, three times — kept whole where the
    two lines turn by less than ``BEND_DEG``."""
    everything = np.ones(len(points), bool)
    if len(points) < 8:
        return [everything]
    centre, direction = _line(points)
    normal = np.array([-direction[1], direction[0]])
    if np.percentile(np.abs((points - centre) @ normal), 95) <= STRAIGHT_MM:
        return [everything]
    first = (points - centre) @ direction < 0
    for _ in range(3):
        if first.sum() < 2 or (~first).sum() < 2:
            return [everything]
        distances = []
        for run in (first, ~first):
            c, d = _line(points[run])
            distances.append(np.abs((points - c) @ np.array([-d[1], d[0]])))
        first = distances[0] <= distances[1]
    if first.sum() < 2 or (~first).sum() < 2:
        return [everything]
    turn = abs(_line(points[first])[1] @ _line(points[~first])[1])
    return [everything] if turn > np.cos(np.radians(BEND_DEG)) else [first, ~first]


def _centroids_uv(raster: Raster, panels: Panels) -> np.ndarray:
    """(count + 1, 2) (u, v) centroid of each panel's cells (row 0: none), from an even
    sample of about 100 000 cells: which side of a seam a panel lies on."""
    stride = max(1, int(np.sqrt(panels.labels.size / 100_000)))
    sample = panels.labels[::stride, ::stride]
    rows, cols = np.nonzero(sample)
    uv = raster.centres_uv(rows * stride, cols * stride)
    found = sample[rows, cols]
    cells = np.maximum(np.bincount(found, minlength=panels.count + 1), 1)
    return np.stack(
        [np.bincount(found, uv[:, k], minlength=panels.count + 1) / cells for k in (0, 1)], 1
    )


BESIDE_MM = (2.5, 8.5)
"""A panel's top runs beside a seam where its cells lie this far beyond the seam's band
somewhere (where the sections fit the tops)."""


def _trim_to_tops(raster: Raster, labels: np.ndarray, seam: SeamLine) -> SeamLine:
    """Cut the seam to where both panel tops run beside it (``BESIDE_MM``). Not only just
    beyond its band: a view that saw through a gap under a panel's edge (open behind the
    panels) put the backing among that top's points, over a wedge millimetres wide and
    tens long, whose cells are no top on the height map — a seam cut where they were lost
    a third of its length (a 2 × 2 assembly scanned at 15° to its seams)."""
    along = np.arange(seam.start_mm - 5.0, seam.end_mm + 5.0, raster.cell_mm)
    offsets = seam.half_band_mm + np.arange(*BESIDE_MM, raster.cell_mm)
    beside = []
    for side, label in ((-1, seam.panels[0]), (1, seam.panels[1])):
        uv = seam.point_uv(along)[:, None] + side * np.multiply.outer(offsets, seam.across_uv)
        rows, cols, inside = raster.cell_at(uv)
        beside.append((inside & (labels[rows, cols] == label)).any(axis=1))
    both = beside[0] & beside[1]
    if not both.any():
        return replace(seam, start_mm=0.0, end_mm=0.0)
    runs = ndimage.label(both)[0]
    longest = np.argmax(np.bincount(runs)[1:]) + 1
    kept = along[runs == longest]
    return replace(seam, start_mm=float(kept.min()), end_mm=float(kept.max()))


def find_junctions(
    seams: list[SeamLine], *, reach_mm: float
) -> tuple[list[SeamLine], list[Junction]]:
    """Ends of three or more seams within ``reach_mm`` of each other meet at a junction:
    the point nearest to all their centre lines. Those seams are extended (or cut) to it."""
    ends = [(i, e) for i in range(len(seams)) for e in (0, 1)]
    points = np.array(
        [
            seams[i].point_uv(np.float64(seams[i].start_mm if e == 0 else seams[i].end_mm))
            for i, e in ends
        ]
    )
    parent = list(range(len(ends)))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    close = np.linalg.norm(points[:, None] - points[None], axis=-1) <= reach_mm
    for k, m in zip(*np.nonzero(np.triu(close, 1)), strict=True):
        parent[root(k)] = root(m)
    groups: dict[int, list[int]] = {}
    for k in range(len(ends)):
        groups.setdefault(root(k), []).append(k)
    junctions = []
    seams = list(seams)
    for members in groups.values():
        seam_ids = {ends[k][0] for k in members}
        if len(seam_ids) < 3 or len(seam_ids) != len(members):
            continue
        normal_sum, rhs = np.zeros((2, 2)), np.zeros(2)
        for k in members:
            seam = seams[ends[k][0]]
            n = seam.across_uv
            normal_sum += np.outer(n, n)
            rhs += np.outer(n, n) @ seam.centre_uv
        at = np.linalg.solve(normal_sum, rhs)
        for k in members:
            i, end = ends[k]
            seam = seams[i]
            along = float((at - seam.centre_uv) @ seam.direction_uv)
            start, stop = (along, seam.end_mm) if end == 0 else (seam.start_mm, along)
            seams[i] = replace(seam, start_mm=start, end_mm=stop)
        junctions.append(
            Junction(at, tuple(ends[k][0] for k in members), tuple(ends[k][1] for k in members))
        )
    return seams, junctions
