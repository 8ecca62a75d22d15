"""The learned car detector at work: a scan's bird's-eye view (``bev``) through the ONNX
model (``nets.BevDetector``, trained by ``detector_training``), its heatmap's peaks decoded
into boxes, overlapping boxes suppressed.

A box's heading is learned modulo half a turn (sin 2θ, cos 2θ): from a car's outline its
front and back look alike, and the tracker's association turns the box to the target's
heading.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from services.lib.boxes import bev_iou
from services.tracking.bev import CELL_M, FULL_VIEW, STRIDE, Window, encode
from services.tracking.detections import Detections, empty_detections

ARCHITECTURE = "bev-centre"
DEFAULT_MODEL = Path(__file__).with_name("models") / "detector.onnx"
"""The detector vista ships (built by ``vista tracking build-default``: see the README), used
when no model is given."""
THRESHOLD = 0.3
MAX_DETECTIONS = 60
NMS_IOU = 0.2


def decode(output: np.ndarray, window: Window, threshold: float = THRESHOLD) -> Detections:
    """Boxes from one image's network output (9, h, w)."""
    heat = 1.0 / (1.0 + np.exp(-output[0]))
    peaks = (heat == ndimage.maximum_filter(heat, size=3)) & (heat >= threshold)
    rows, cols = np.nonzero(peaks)
    if not len(rows):
        return empty_detections()
    order = np.argsort(-heat[rows, cols])[:MAX_DETECTIONS]
    rows, cols = rows[order], cols[order]
    cell = CELL_M * STRIDE
    values = output[:, rows, cols]
    boxes = np.column_stack(
        [
            window.x0_m + (rows + values[1]) * cell,
            window.y0_m + (cols + values[2]) * cell,
            values[3],
            np.exp(np.clip(values[4:7].T, -3, 3)),
            0.5 * np.arctan2(values[7], values[8]),
        ]
    )
    scores = heat[rows, cols]
    keep = _suppress(boxes, scores)
    return Detections(boxes[keep], scores[keep], np.zeros(int(keep.sum()), dtype=np.int64))


def _suppress(boxes: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """(D,) bool: each box not overlapping a higher-scored kept one by more than ``NMS_IOU``
    (bird's-eye IoU); ``boxes`` come sorted by score."""
    overlap = bev_iou(boxes[:, None, :], boxes[None, :, :])
    keep = np.ones(len(boxes), dtype=bool)
    for index in range(len(boxes)):
        if keep[index]:
            later = np.arange(len(boxes)) > index
            keep &= ~(later & (overlap[index] > NMS_IOU))
    return keep


class LearnedDetector:
    """The pipeline's learned detector branch: an ONNX model file of ``ARCHITECTURE``, its
    boxes kept from the score its metadata gives (or ``threshold``)."""

    name = "learned"

    def __init__(self, model: Path, *, threads: int = 1, threshold: float | None = None) -> None:
        from services.lib.nn.onnx_io import read_model, session

        found = read_model(Path(model))
        if found.metadata.get("architecture") != ARCHITECTURE:
            raise ValueError(
                f"{model}: a {found.metadata.get('architecture')!r} model, not vista's car detector "
                f"({ARCHITECTURE}); build one with `vista tracking train`"
            )
        self.metadata = found.metadata
        self.threshold = float(
            threshold if threshold is not None else found.metadata.get("threshold", THRESHOLD)
        )
        self.session = session(Path(model), threads=threads)

    def detect(self, points: np.ndarray, region: np.ndarray | None = None) -> Detections:
        window = Window.around(FULL_VIEW if region is None else region)
        image = encode(points, window)[None]
        (output,) = self.session.run(None, {"bev": image})
        return decode(output[0], window, self.threshold)
