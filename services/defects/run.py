"""The measure verb's one core function: a cloud file, the tolerances and the measurement
settings in, the measurement out. `vista defects measure` and the `defects.measure` job
both call it; each only reads its arguments and says what was found."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.tolerances import Tolerances, limits_of
from contract.vocabulary import Progress
from services.defects.config import MeasureConfig, measure_config
from services.defects.kinds import MeasureSettings
from services.defects.measure import MeasureError, MeasureResult, measure
from services.defects.report import profile_png, result_document
from services.lib.pointcloud.scanner import load_cloud


@dataclass(frozen=True)
class Measured:
    result: MeasureResult
    config: MeasureConfig
    """The tolerances and settings it was measured with."""
    document: dict
    """RESULT.json."""
    cloud_bounds_mm: list[list[float]]
    """The cloud's axis-aligned box, [min, max]: the area this measurement covers (an
    earlier finding inside it that this one did not find again is no longer current)."""

    def draw_profiles(self, path: Path) -> None:
        """The seams' gap and step profiles with the tolerance limits, as a PNG."""
        profile_png(self.result, self.config, path)


def measure_cloud(
    cloud: Path,
    tolerances: Tolerances,
    settings: MeasureSettings,
    *,
    threads: int,
    progress: Progress | None = None,
) -> Measured:
    """Measure the cloud file ``cloud`` (vista's PLY, or any format ``load_cloud`` reads,
    in mm) as ``settings`` say, judged against ``tolerances``, on ``threads`` threads.
    MeasureError: the file is no cloud vista reads, or holds no panel assembly (the
    message names it)."""
    config = measure_config(limits_of(tolerances), settings)
    try:
        points = load_cloud(cloud)
    except ValueError as exc:  # PlyError, a scanner format's error
        raise MeasureError(str(exc)) from exc
    try:
        result = measure(points, config, threads=threads, progress=progress)
    except MeasureError as exc:
        raise MeasureError(f"{cloud}: {exc}") from exc
    document = result_document(result, config)
    return Measured(result, config, document, _bounds_mm(points.points))


def _bounds_mm(points: np.ndarray) -> list[list[float]]:
    finite = points[np.isfinite(points).all(axis=1)]
    return [np.round(finite.min(axis=0), 2).tolist(), np.round(finite.max(axis=0), 2).tolist()]
