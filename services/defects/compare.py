"""The compare verb's one core function: a cloud file and its nominal in, aligned, each
point's signed deviation, per region its statistics and coverage, the areas beyond the
profile band as findings. `vista defects compare` and the `defects.compare` job both call
it; each only reads its arguments and says what was found."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.tolerances import Limits, Tolerances, limits_of
from contract.vocabulary import Progress
from services.defects.align import AlignError, Alignment, best_fit, given, reference_points
from services.defects.deviation import STRAY_MM, Deviation, judge_deviation
from services.defects.kinds import CompareParams
from services.lib.pointcloud.mesh_distance import MeshIndex, index_mesh, signed_distance
from services.lib.pointcloud.nominal import Nominal, NominalError, read_nominal
from services.lib.pointcloud.ply import PointCloud, write_ply
from services.lib.pointcloud.scanner import load_cloud
from services.lib.pointcloud.transforms import apply

HISTOGRAM_BINS = 80
OFF_NOMINAL_SHARE = 0.5
"""More of the scan than this off the nominal (strays): a warning."""
LEAST_COVERAGE = 0.1
"""No region of the nominal covered more than this: a warning."""
NOISE_SHARE = 0.5
"""The scan's robust σ about the nominal over this share of the band's half-width: a
warning."""


class CompareError(ValueError):
    """The cloud or the nominal cannot be compared; the message says which and why."""


@dataclass(frozen=True)
class Compared:
    nominal: Nominal
    alignment: Alignment
    deviation: Deviation
    limits: Limits
    aligned_mm: np.ndarray
    """(N, 3) the cloud in the nominal's frame."""
    color_scale_mm: float
    seconds: dict[str, float]
    document: dict
    """RESULT.json."""

    def write_cloud(self, path: Path) -> None:
        """The aligned cloud coloured by deviation (blue below, red above, white on the
        nominal; saturated at ± the colour scale, grey for strays), the deviation as the
        scalar field ``deviation``."""
        colours = deviation_colours(self.deviation.deviation_mm, self.color_scale_mm)
        cloud = PointCloud(self.aligned_mm.astype(np.float32), colors=colours)
        write_ply(path, cloud, comments=("vista deviation from nominal, mm (strays NaN)",),
                  scalars={"deviation": self.deviation.deviation_mm.astype(np.float32)})  # fmt: skip

    def write_histogram(self, path: Path) -> None:
        """The deviations' histogram with the profile band, as a PNG."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        histogram = self.document["histogram"]
        edges, counts = np.array(histogram["edges_mm"]), np.array(histogram["counts"])
        figure, axes = plt.subplots(figsize=(7, 3.2), dpi=110)
        centres = (edges[:-1] + edges[1:]) / 2
        colours = deviation_colours(centres, self.color_scale_mm) / 255.0
        axes.bar(centres, counts, width=np.diff(edges), color=colours, edgecolor="#555", lw=0.3)
        for limit in (self.limits.profile_min_mm, self.limits.profile_max_mm):
            axes.axvline(limit, color="#c00", ls="--", lw=1)
        axes.set_xlabel("deviation from nominal (mm)")
        axes.set_ylabel("points")
        axes.set_title(
            f"{self.document['points']} points; band {self.limits.profile_min_mm:+.2f} … "
            f"{self.limits.profile_max_mm:+.2f} mm"
        )
        figure.tight_layout()
        figure.savefig(path)
        plt.close(figure)

    def region_table(self) -> str:
        """The per-region table as CSV."""
        header = "region,points,mean_mm,sigma_mm,min_mm,max_mm,within_share,coverage_share,band_min_mm,band_max_mm"
        rows = []
        for region in self.document["regions"]:
            cells = [region["region"], *(region[k] for k in (
                "points", "mean_mm", "sigma_mm", "min_mm", "max_mm", "within_share",
                "coverage_share")), *region["band_mm"]]  # fmt: skip
            rows.append(",".join("" if c is None else str(c) for c in cells))
        return "\n".join([header, *rows]) + "\n"


def compare_cloud(
    cloud: Path,
    nominal: Path,
    tolerances: Tolerances,
    params: CompareParams,
    *,
    threads: int,
    progress: Progress | None = None,
) -> Compared:
    """Compare the cloud file ``cloud`` (mm) with the nominal file ``nominal`` as
    ``params`` say, judged against ``tolerances``' profile bands, on ``threads`` threads.
    CompareError: a file vista does not read, or an alignment that cannot be made."""
    say = progress or (lambda fraction, message: None)
    seconds: dict[str, float] = {}
    clock = time.perf_counter()
    try:
        model = read_nominal(nominal)
    except (NominalError, OSError) as exc:
        raise CompareError(f"{nominal} {exc}") from exc
    try:
        points = load_cloud(cloud).points.astype(np.float64)
    except ValueError as exc:
        raise CompareError(f"{cloud}: {exc}") from exc
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < 6:
        raise CompareError(f"{cloud}: {len(points)} points; a comparison needs at least 6")
    seconds["read"] = time.perf_counter() - clock
    say(0.1, f"indexing the nominal's {len(model.mesh.faces)} triangles")
    clock = time.perf_counter()
    index = index_mesh(model.mesh)
    seconds["index"] = time.perf_counter() - clock
    say(0.2, f"aligning ({params.align})")
    clock = time.perf_counter()
    try:
        alignment = _align(index, points, params, threads)
    except AlignError as exc:
        raise CompareError(str(exc)) from exc
    seconds["align"] = time.perf_counter() - clock
    say(0.6, f"measuring {len(points)} points' deviation")
    clock = time.perf_counter()
    aligned = apply(alignment.nominal_T_cloud, points)
    distance = signed_distance(index, aligned, threads)
    seconds["distance"] = time.perf_counter() - clock
    say(0.8, "judging against the profile band")
    clock = time.perf_counter()
    limits = limits_of(tolerances)
    deviation = judge_deviation(
        aligned, distance, model.mesh, model.region_of_face, model.regions, limits,
        sigma_mm=alignment.residual_robust_mm,
    )  # fmt: skip
    seconds["judge"] = time.perf_counter() - clock
    judged = deviation.deviation_mm[np.isfinite(deviation.deviation_mm)]
    if len(judged) == 0:
        raise CompareError(
            f"none of the {len(points)} points lies within {STRAY_MM:g} mm of the nominal "
            f"after aligning ({params.align}): the wrong nominal, or the wrong units — "
            "nothing was compared"
        )
    alignment = alignment.measured_on(judged)
    warnings = trust_warnings(deviation, limits, alignment)
    scale = params.color_scale_mm or max(abs(limits.profile_min_mm), limits.profile_max_mm, 1e-3)
    document = _document(cloud, nominal, model, alignment, deviation, limits, scale, seconds)
    document["warnings"] = warnings
    return Compared(model, alignment, deviation, limits, aligned, scale, seconds, document)


def trust_warnings(deviation: Deviation, limits: Limits, alignment: Alignment) -> list[str]:
    """What a person must know before reading the comparison as a pass: most of the scan
    off the nominal (its findings and statistics are of the rest only), the nominal
    barely covered, or the scan's noise after alignment too close to the band for a
    deviation near it to be told apart."""
    warnings = []
    points = len(deviation.deviation_mm)
    if deviation.strays > OFF_NOMINAL_SHARE * points:
        warnings.append(
            f"{100 * deviation.strays / points:.0f} % of the scan lies off the nominal "
            "(strays): the wrong nominal, or an alignment that failed — only the rest is judged"
        )
    covered = max((r.coverage_share for r in deviation.regions), default=0.0)
    if covered < LEAST_COVERAGE:
        warnings.append(
            f"the scan covers at most {100 * covered:.0f} % of any region of the nominal: "
            "what it did not cover is not judged"
        )
    half_band = min(-limits.profile_min_mm, limits.profile_max_mm)
    if alignment.residual_robust_mm > NOISE_SHARE * half_band:
        warnings.append(
            f"the scan's spread about the nominal (robust σ {alignment.residual_robust_mm:.3f} "
            f"mm) is over {NOISE_SHARE:g} of the band's half-width ({half_band:g} mm): a "
            "deviation near the band cannot be told from it"
        )
    return warnings


def _align(index: MeshIndex, points: np.ndarray, params: CompareParams, threads: int) -> Alignment:
    if params.align == "given":
        return given(index, points, workers=threads)
    if params.align == "points":
        assert params.reference_points is not None  # CompareParams checks it
        return reference_points(
            {k: list(v) for k, v in params.reference_points.nominal.items()},
            {k: list(v) for k, v in params.reference_points.scan.items()},
        )
    start = np.eye(4) if params.start == "as-is" else None
    return best_fit(index, points, start, workers=threads)


def _document(cloud: Path, nominal: Path, model: Nominal, alignment: Alignment,
              deviation: Deviation, limits: Limits, scale: float,
              seconds: dict[str, float]) -> dict:  # fmt: skip
    values = deviation.deviation_mm[np.isfinite(deviation.deviation_mm)]
    counts, edges = np.histogram(np.clip(values, -2 * scale, 2 * scale), HISTOGRAM_BINS,
                                 range=(-2 * scale, 2 * scale))  # fmt: skip
    findings = [f.document() for f in deviation.findings]
    return {
        "cloud": cloud.name,
        "nominal": {
            "file": nominal.name,
            "format": model.format,
            "triangles": len(model.mesh.faces),
            "regions": list(model.regions),
            "scaled_to_mm_by": model.scale_to_mm,
        },
        "points": int(len(deviation.deviation_mm)),
        "strays": deviation.strays,
        "spacing_mm": round(deviation.spacing_mm, 4),
        "profile_band_mm": [limits.profile_min_mm, limits.profile_max_mm],
        "color_scale_mm": scale,
        "alignment": alignment.document(),
        "regions": [r.document() for r in deviation.regions],
        "defects": [f for f in findings if f["tolerance_state"] == "out"],
        "uncertain": [f for f in findings if f["tolerance_state"] == "uncertain"],
        "histogram": {"edges_mm": np.round(edges, 5).tolist(), "counts": counts.tolist()},
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
    }


def deviation_colours(deviation_mm: np.ndarray, scale_mm: float) -> np.ndarray:
    """(N, 3) uint8: a diverging map, blue (−scale) through white (0) to red (+scale),
    saturated beyond; grey where not finite."""
    t = np.clip(np.nan_to_num(deviation_mm, nan=0.0) / scale_mm, -1.0, 1.0)
    white = np.array([247.0, 247.0, 247.0])
    red, blue = np.array([178.0, 24.0, 43.0]), np.array([33.0, 102.0, 172.0])
    above = np.clip(t, 0, 1)[:, None]
    below = np.clip(-t, 0, 1)[:, None]
    colours = white + above * (red - white) + below * (blue - white)
    colours[~np.isfinite(deviation_mm)] = (128, 128, 128)
    return np.round(colours).astype(np.uint8)
