"""Depth evaluation exactly as monodepth2's ``evaluate_depth.py``: per image, the ground
truth's valid pixels (``min_depth`` < d < ``max_depth``) inside a crop; the prediction resized
to the ground truth's size, optionally scaled by the ratio of medians, clipped to
[``min_depth``, ``max_depth``]; seven metrics; their means over images.

Crops (fractions of height and width: top, bottom, left, right):
- ``garg``: 0.40810811, 0.99189189, 0.03594771, 0.96405229 — Garg et al.'s, which
  monodepth2 applies on its Eigen split;
- ``eigen``: 0.3324324, 0.91351351, 0.0359477, 0.96405229 — Eigen et al.'s original;
- ``none``: the whole image.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

MIN_DEPTH_M = 1e-3
MAX_DEPTH_M = 80.0
CROPS = {
    "garg": (0.40810811, 0.99189189, 0.03594771, 0.96405229),
    "eigen": (0.3324324, 0.91351351, 0.0359477, 0.96405229),
    "none": (0.0, 1.0, 0.0, 1.0),
}
METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "delta1", "delta2", "delta3")


@dataclass(frozen=True)
class DepthErrors:
    abs_rel: float
    sq_rel: float
    rmse: float
    """Metres."""
    rmse_log: float
    delta1: float
    """Share of pixels with max(gt/pred, pred/gt) < 1.25."""
    delta2: float
    delta3: float

    def to_json(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class ImageEvaluation:
    errors: DepthErrors
    pixels: int
    """Valid ground-truth pixels evaluated."""
    scale: float
    """The median ratio applied (1 without median scaling)."""


def errors(gt_m: np.ndarray, pred_m: np.ndarray) -> DepthErrors:
    """The seven metrics between matching 1-D arrays of positive depths (metres)."""
    ratio = np.maximum(gt_m / pred_m, pred_m / gt_m)
    return DepthErrors(
        abs_rel=float(np.mean(np.abs(gt_m - pred_m) / gt_m)),
        sq_rel=float(np.mean((gt_m - pred_m) ** 2 / gt_m)),
        rmse=float(np.sqrt(np.mean((gt_m - pred_m) ** 2))),
        rmse_log=float(np.sqrt(np.mean((np.log(gt_m) - np.log(pred_m)) ** 2))),
        delta1=float(np.mean(ratio < 1.25)),
        delta2=float(np.mean(ratio < 1.25**2)),
        delta3=float(np.mean(ratio < 1.25**3)),
    )


def evaluate_image(
    gt_m: np.ndarray,
    pred_m: np.ndarray,
    *,
    crop: str = "garg",
    median_scaling: bool = False,
    min_depth_m: float = MIN_DEPTH_M,
    max_depth_m: float = MAX_DEPTH_M,
) -> ImageEvaluation:
    """One image: ``gt_m`` (H, W) with 0 where unmeasured, ``pred_m`` (h, w) resized
    bilinearly to (H, W) when it differs. ValueError when no pixel is valid."""
    import cv2

    if crop not in CROPS:
        raise ValueError(f"crop {crop!r}: known crops are {', '.join(CROPS)}")
    if max_depth_m <= min_depth_m:
        raise ValueError(f"max depth {max_depth_m} m must exceed min depth {min_depth_m} m")
    gt = np.asarray(gt_m, dtype=np.float64)
    pred = np.asarray(pred_m, dtype=np.float32)
    if gt.ndim != 2 or pred.ndim != 2:
        raise ValueError(f"depth maps are (H, W): ground truth {gt.shape}, prediction {pred.shape}")
    height, width = gt.shape
    if pred.shape != gt.shape:
        pred = cv2.resize(pred, (width, height), interpolation=cv2.INTER_LINEAR)
    top, bottom, left, right = CROPS[crop]
    box = (np.array([top * height, bottom * height, left * width, right * width])).astype(np.int32)
    in_crop = np.zeros(gt.shape, bool)
    in_crop[box[0] : box[1], box[2] : box[3]] = True
    mask = (gt > min_depth_m) & (gt < max_depth_m) & in_crop
    if not mask.any():
        raise ValueError("no ground-truth pixel inside the crop and depth range")
    truth, guess = gt[mask], pred[mask].astype(np.float64)
    scale = 1.0
    if median_scaling:
        middle = float(np.median(guess))
        if middle <= 0:
            raise ValueError("the prediction's median depth is not positive: cannot median-scale")
        scale = float(np.median(truth)) / middle
        guess = guess * scale
    guess = np.clip(guess, min_depth_m, max_depth_m)
    return ImageEvaluation(errors(truth, guess), int(mask.sum()), scale)


def mean_errors(evaluations: list[ImageEvaluation]) -> DepthErrors:
    """Each metric averaged over images (monodepth2's: every image counts alike)."""
    if not evaluations:
        raise ValueError("no image to average")
    rows = np.array([[getattr(e.errors, m) for m in METRICS] for e in evaluations])
    return DepthErrors(*(float(v) for v in rows.mean(axis=0)))


@dataclass(frozen=True)
class FolderEvaluation:
    metrics: DepthErrors
    images: list[dict]
    """Per image: ``name``, the seven metrics, ``pixels``, ``scale``."""
    missing: list[str]
    """Ground-truth names without a prediction (not evaluated)."""
    unmatched: list[str]
    """Prediction names without ground truth (not evaluated)."""

    def to_json(self) -> dict:
        return {
            "metrics": self.metrics.to_json(),
            "images": self.images,
            "missing": self.missing,
            "unmatched_predictions": self.unmatched,
        }


def evaluate_folders(
    pred_dir: Path,
    gt_dir: Path,
    *,
    crop: str = "garg",
    median_scaling: bool = False,
    max_depth_m: float = MAX_DEPTH_M,
) -> FolderEvaluation:
    """Every ground-truth depth PNG in ``gt_dir`` against the prediction of the same name in
    ``pred_dir`` (KITTI depth PNGs; a prediction's ``*.color.png`` preview is ignored); the
    names on one side only are listed in the result (``missing``, ``unmatched``)."""
    from services.lib.kitti import read_depth_png

    for folder, what in ((pred_dir, "predictions"), (gt_dir, "ground truth")):
        if not Path(folder).is_dir():
            raise ValueError(f"{folder}: no such folder ({what})")
    truths = {p.stem: p for p in sorted(Path(gt_dir).glob("*.png"))}
    predictions = {
        p.stem: p for p in Path(pred_dir).glob("*.png") if not p.name.endswith(".color.png")
    }
    names = [n for n in truths if n in predictions]
    if not names:
        raise ValueError(
            f"no prediction in {pred_dir} has the name of a ground-truth PNG in {gt_dir} "
            f"({len(predictions)} predictions, {len(truths)} ground truths)"
        )
    images, evaluations = [], []
    for name in names:
        try:
            result = evaluate_image(
                read_depth_png(truths[name]),
                read_depth_png(predictions[name]),
                crop=crop,
                median_scaling=median_scaling,
                max_depth_m=max_depth_m,
            )
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
        evaluations.append(result)
        images.append(
            {
                "name": name,
                **result.errors.to_json(),
                "pixels": result.pixels,
                "scale": result.scale,
            }
        )
    missing = [n for n in truths if n not in predictions]
    unmatched = [n for n in predictions if n not in truths]
    return FolderEvaluation(mean_errors(evaluations), images, missing, sorted(unmatched))
