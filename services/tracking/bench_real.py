"""The real-scan half of ``vista tracking bench``: KITTI's labelled scans in ``../shared/data``.

- **Which scans check what.** The shipped detector was fine-tuned on the 19 object scans
  and never saw the labelled drive (0048): that drive is its held-out check. To hold the
  object scans out too, the same recipe is re-run in ``FOLDS`` folds — the simulator-only
  model fine-tuned on two thirds of the object scans, checked on the third it did not see
  — so every labelled real scan is checked by a model that never trained on it.
- **Detection** on those scans: recall of cars within 40 m at BEV IoU ≥ 0.5 and precision
  in the camera's view, with 95 % intervals (``detection_eval``), and milliseconds a scan.
- **Tracking** on the labelled drive: every car labelled in at least ``MIN_LABELLED``
  frames, tracked through every frame from its first labelled one, scored on the labelled
  frames (every other one).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.bench import say
from services.lib import kitti
from services.tracking.datasets import LabelledScan, labelled_scans
from services.tracking.default_detector import REAL_HELD_OUT, REAL_TRAIN, fine_tuned
from services.tracking.detection_eval import combine, match_scan
from services.tracking.pipeline import Detector
from services.tracking.sequence import Sequence, Tracklet, open_sequence, tracklets

FOLDS = 3
MIN_LABELLED = 3


@dataclass(frozen=True)
class RealData:
    trained: list[LabelledScan]
    """The object scans (the shipped model's fine-tuning data)."""
    held_out: list[LabelledScan]
    """The labelled drive's scans (no model here trained on them)."""
    drive: Sequence


def real_data() -> RealData | None:
    """The shared real scans, or None when ``../shared/data`` is not here."""
    if not (REAL_TRAIN.is_dir() and REAL_HELD_OUT.is_dir()):
        return None
    return RealData(
        labelled_scans([REAL_TRAIN]), labelled_scans([REAL_HELD_OUT]), open_sequence(REAL_HELD_OUT)
    )


def fold_of(items: list[LabelledScan], folds: int = FOLDS) -> np.ndarray:
    """(N,) each scan's fold: scans dealt out in order of their cars within 40 m, most
    first, so that each fold holds about as many."""
    near = [int((np.hypot(i.cars[:, 0], i.cars[:, 1]) <= 40).sum()) for i in items]
    order = np.argsort(-np.array(near), kind="stable")
    fold = np.empty(len(items), dtype=int)
    fold[order] = np.arange(len(items)) % folds
    return fold


def linked_object_folder(items: list[LabelledScan], folder: Path) -> Path:
    """An object folder of links to ``items``' files (no copy of the data)."""
    for sub in ("velodyne", "calib", "label_2"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    for item in items:
        stem = item.path.stem
        root = item.path.parent.parent
        for sub, suffix in (("velodyne", ".bin"), ("calib", ".txt"), ("label_2", ".txt")):
            link = folder / sub / f"{stem}{suffix}"
            if not link.exists():
                link.symlink_to(root / sub / f"{stem}{suffix}")
    return folder


def cross_validation_models(
    data: RealData, base: Path, paste_from: list[Path], work: Path, seed: int = 0
) -> list[tuple[Path, list[LabelledScan]]]:
    """The recipe re-run per fold: (model, the object scans it never saw), kept in
    ``work/cv``."""
    fold = fold_of(data.trained)
    out = []
    for k in range(FOLDS):
        train = [item for item, f in zip(data.trained, fold, strict=True) if f != k]
        test = [item for item, f in zip(data.trained, fold, strict=True) if f == k]
        model = work / "cv" / f"fold{k}.onnx"
        if not model.is_file():
            fine_tuned(
                base,
                [linked_object_folder(train, work / "cv" / f"fold{k}-train")],
                model,
                validate_on=[linked_object_folder(test, work / "cv" / f"fold{k}-test")],
                paste_from=paste_from,
                seed=seed,
                work=work,
                say=say,
                command=f"vista tracking bench: the shipped model's recipe, fold {k + 1} of {FOLDS}",
            )
        out.append((model, test))
    return out


def detection_scores(detector: Detector, items: list[LabelledScan]) -> dict:
    """Recall, precision (with intervals) and milliseconds a scan over full scans."""
    tallies, seconds = [], 0.0
    for item in items:
        points = kitti.read_velodyne(item.path)
        started = time.perf_counter()
        found = detector.detect(points)
        seconds += time.perf_counter() - started
        tallies.append(match_scan(found, item.labels, item.calibration).tally())
    document = combine(tallies, 40.0, getattr(detector, "threshold", float("nan"))).document()
    document["ms_per_scan"] = round(1000 * seconds / max(len(items), 1), 1)
    return document


def pooled(parts: list[dict]) -> dict:
    """Scores of several (model, scans) parts as one: counts summed, ratios and intervals
    recomputed, milliseconds averaged by scans."""
    from services.tracking.detection_eval import ScanTally

    fields = [f for f in ScanTally.__dataclass_fields__ if f != "ignored"]
    total = ScanTally(**{f: sum(p[f] for p in parts) for f in fields}, ignored=0)
    document = combine([total], 40.0, parts[0]["score_threshold"]).document()
    document["scans"] = sum(p["scans"] for p in parts)
    document["ms_per_scan"] = round(
        sum(p["ms_per_scan"] * p["scans"] for p in parts) / max(document["scans"], 1), 1
    )
    return document


def drive_tracklets(drive: Sequence) -> list[Tracklet]:
    """The labelled drive's car tracklets with at least ``MIN_LABELLED`` labelled frames."""
    return [t for t in tracklets(drive, ("Car",), 2) if t.labelled.sum() >= MIN_LABELLED]
