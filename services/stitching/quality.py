"""Stitching quality (thesis Fig. 6.2): for every pair of overlapping scans, the distance
from each point of one to the nearest point of the other inside their common region.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

HISTOGRAM_BIN_MM = 0.01
SURFACE_GAP_MM = 2.0
"""Points farther than this from the other scan are off its surface (a hole, an edge it did
not see), not a stitching error, and are counted apart."""


@dataclass(frozen=True)
class Distances:
    count: int
    mean_mm: float
    std_mm: float
    p90_mm: float
    max_mm: float

    @staticmethod
    def of(values: np.ndarray) -> Distances:
        if len(values) == 0:
            return Distances(0, float("nan"), float("nan"), float("nan"), float("nan"))
        return Distances(
            int(len(values)),
            float(values.mean()),
            float(values.std()),
            float(np.percentile(values, 90)),
            float(values.max()),
        )


@dataclass(frozen=True)
class PairQuality:
    scans: tuple[int, int]
    distances: Distances
    off_surface: int
    histogram: list[int]
    """Counts per HISTOGRAM_BIN_MM bin from 0."""


@dataclass(frozen=True)
class QualityReport:
    pairs: list[PairQuality]
    overall: Distances
    bounds_min_mm: list[float]
    bounds_max_mm: list[float]
    model_bounds_difference_mm: list[float] | None = None
    """|stitched − model| per bounding-box face (min x, y, z, max x, y, z), simulation only."""
    true_error: Distances | None = None
    """Distance of the stitched points to the true surface, simulation only."""

    def to_json(self) -> dict:
        return asdict(self)


def _box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return points.min(axis=0), points.max(axis=0)


def overlap_distances(
    source: np.ndarray, target: np.ndarray, *, sample: int, rng: np.random.Generator
) -> tuple[np.ndarray, int]:
    """Distances (mm) from up to ``sample`` source points inside the two clouds' common
    bounding box to their nearest target point, and how many were off the target's surface."""
    low = np.maximum(source.min(0), target.min(0))
    high = np.minimum(source.max(0), target.max(0))
    if np.any(low > high):
        return np.empty(0), 0
    inside_source = source[np.all((source >= low) & (source <= high), axis=1)]
    inside_target = target[np.all((target >= low - 1.0) & (target <= high + 1.0), axis=1)]
    if len(inside_source) == 0 or len(inside_target) == 0:
        return np.empty(0), 0
    if len(inside_source) > sample:
        inside_source = inside_source[rng.choice(len(inside_source), sample, replace=False)]
    distances, _ = cKDTree(inside_target).query(inside_source, workers=-1)
    on_surface = distances <= SURFACE_GAP_MM
    return distances[on_surface], int((~on_surface).sum())


def quality_report(
    scans: list[np.ndarray],
    stitched: np.ndarray,
    *,
    min_overlap_points: int = 1000,
    sample: int = 200_000,
    seed: int = 0,
    model_bounds_mm: tuple[np.ndarray, np.ndarray] | None = None,
    true_distance_mm: np.ndarray | None = None,
) -> QualityReport:
    """scans : per scan (N_i, 3) base-frame points (cleaned, not merged); stitched : (M, 3)."""
    rng = np.random.default_rng(seed)
    boxes = [_box(s) for s in scans]
    pairs, every = [], []
    for i in range(len(scans)):
        for j in range(i + 1, len(scans)):
            if np.any(np.maximum(boxes[i][0], boxes[j][0]) > np.minimum(boxes[i][1], boxes[j][1])):
                continue
            distances, off = overlap_distances(scans[i], scans[j], sample=sample, rng=rng)
            if len(distances) < min_overlap_points:
                continue
            bins = np.arange(0.0, distances.max() + 2 * HISTOGRAM_BIN_MM, HISTOGRAM_BIN_MM)
            counts, _ = np.histogram(distances, bins=bins)
            pairs.append(PairQuality((i, j), Distances.of(distances), off, counts.tolist()))
            every.append(distances)
    low, high = _box(stitched)
    difference = None
    if model_bounds_mm is not None:
        difference = np.abs(np.concatenate([low - model_bounds_mm[0], high - model_bounds_mm[1]]))
        difference = difference.tolist()
    return QualityReport(
        pairs=pairs,
        overall=Distances.of(np.concatenate(every) if every else np.empty(0)),
        bounds_min_mm=low.tolist(),
        bounds_max_mm=high.tolist(),
        model_bounds_difference_mm=difference,
        true_error=None if true_distance_mm is None else Distances.of(true_distance_mm),
    )


def histogram_png(report: QualityReport, path: Path) -> None:
    """The overlap distance histogram of every pair and its cumulative share (Fig. 6.2)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 4), dpi=110)
    width = max((len(p.histogram) for p in report.pairs), default=1)
    total = np.zeros(width)
    for pair in report.pairs:
        total[: len(pair.histogram)] += pair.histogram
    edges = np.arange(width) * HISTOGRAM_BIN_MM
    axis.bar(edges, total, width=HISTOGRAM_BIN_MM, align="edge", color="#4c78a8")
    axis.set_xlabel("distance to the nearest point of the overlapping scan (mm)")
    axis.set_ylabel("points")
    cumulative = axis.twinx()
    cumulative.plot(
        edges + HISTOGRAM_BIN_MM, np.cumsum(total) / max(total.sum(), 1), color="#e45756"
    )
    cumulative.set_ylabel("cumulative share")
    cumulative.set_ylim(0, 1.02)
    o = report.overall
    axis.set_title(
        f"{len(report.pairs)} overlapping pairs: mean {o.mean_mm:.4f} mm, "
        f"std {o.std_mm:.4f}, p90 {o.p90_mm:.4f}, max {o.max_mm:.3f}"
    )
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
