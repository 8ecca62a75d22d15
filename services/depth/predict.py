"""Depth for images — ``vista depth predict`` and the ``depth.predict`` job alike
(``predict_depth``): each image resized to the model's input, the depth resized back to the
image's own size and written in KITTI's convention, with a colour preview and, when asked,
a point cloud.

- ``NAME.png``: uint16, metres × 256 (0 = none), the input's size;
- ``NAME.color.png``: inverse depth through the magma colour map (near bright), a colour bar
  in metres below;
- ``NAME.ply``: the camera-frame cloud (x right, y down, z forward), float32 mm with the
  image's colours, organised as the image's grid (NaN where there is no depth).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.vocabulary import Progress
from services.depth.camera import PinholeCamera
from services.depth.drive import image_files, read_calibration, read_calibration_file
from services.depth.kinds import PredictParams
from services.depth.models import DepthModel, default_model
from services.depth.quantize import CALIBRATION_IMAGES, quantize_int8
from services.lib.images import read_image
from services.lib.kitti import write_depth_png

CLOUD_MAX_DEPTH_M = 80.0
"""Beyond this the cloud leaves a point out (KITTI's evaluation cap)."""


@dataclass(frozen=True)
class PredictedImage:
    name: str
    image_path: Path
    depth_path: Path
    colour_path: Path
    cloud_path: Path | None
    width: int
    height: int
    seconds: float
    """The model's run alone (resizing and files excluded)."""
    median_depth_m: float


def resize_for(model: DepthModel, image: np.ndarray) -> np.ndarray:
    import cv2

    spec = model.spec
    if image.shape[:2] == (spec.height, spec.width):
        return image
    shrink = image.shape[1] > spec.width
    return cv2.resize(
        image,
        (spec.width, spec.height),
        interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR,
    )


def predict_image(model: DepthModel, image: np.ndarray) -> tuple[np.ndarray, float]:
    """(H, W) depth in metres at the image's own size and the model's seconds."""
    import cv2

    started = time.perf_counter()
    depth = model.predict(resize_for(model, image)[None]).depth_m[0]
    seconds = time.perf_counter() - started
    if depth.shape != image.shape[:2]:
        depth = cv2.resize(depth, (image.shape[1], image.shape[0]), interpolation=cv2.INTER_LINEAR)
    return depth, seconds


BAR_TICKS_M = (1, 2, 3, 5, 10, 20, 30, 50, 100)


def colour_preview(depth_m: np.ndarray) -> np.ndarray:
    """(H + bar, W, 3) uint8 BGR: inverse depth scaled to its 95th percentile, magma, over a
    colour bar labelled in metres (far on the left, near on the right)."""
    import cv2

    inverse = np.where(depth_m > 0, 1 / np.maximum(depth_m, 1e-3), 0)
    top = float(np.percentile(inverse, 95)) or 1.0
    image = cv2.applyColorMap(
        np.clip(inverse / top * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_MAGMA
    )
    return np.vstack((image, colour_bar(image.shape[1], top)))


ERROR_FULL_SCALE = 0.5
"""An error preview's red: a relative error of 50 % or more."""


def error_preview(
    gt_m: np.ndarray, pred_m: np.ndarray, scale: float, image_rgb: np.ndarray
) -> np.ndarray:
    """(H, W, 3) uint8 BGR: at each ground-truth pixel the relative error |gt − s·pred| / gt
    of the prediction scaled by ``scale``, green (0) through yellow to red (≥ 50 %), each
    measured pixel grown to 5 × 5 (LiDAR ground truth is sparse), over the camera image in
    dim grey."""
    import cv2

    height, width = gt_m.shape
    pred = cv2.resize(pred_m.astype(np.float32), (width, height), interpolation=cv2.INTER_LINEAR)
    measured = gt_m > 0
    relative = np.zeros(gt_m.shape, np.float32)
    relative[measured] = np.abs(gt_m[measured] - scale * pred[measured]) / gt_m[measured]
    level = np.clip(relative / ERROR_FULL_SCALE, 0, 1)
    bgr = np.zeros((height, width, 3), np.uint8)
    bgr[..., 1] = np.where(measured, 255 * np.clip(2 - 2 * level, 0, 1), 0)
    bgr[..., 2] = np.where(measured, 255 * np.clip(2 * level, 0, 1), 0)
    # each measured pixel's colour over its 5 × 5 neighbourhood (the nearest measured wins)
    kernel = np.ones((5, 5), np.uint8)
    grown = cv2.dilate(bgr, kernel)
    covered = cv2.dilate(measured.astype(np.uint8), kernel).astype(bool)
    grey = cv2.cvtColor(cv2.resize(image_rgb, (width, height)), cv2.COLOR_RGB2GRAY)
    background = np.repeat((0.35 * grey)[..., None], 3, axis=2).astype(np.uint8)
    return np.where(covered[..., None], grown, background)


def colour_bar(width: int, top_inverse_m: float) -> np.ndarray:
    """(h, width, 3) uint8 BGR: the preview's colours from 0 to ``top_inverse_m`` (1/m)
    with ticks at round depths, labelled in metres."""
    import cv2

    height = max(28, width // 24)
    ramp = np.linspace(0, 255, width).astype(np.uint8)
    strip = cv2.applyColorMap(np.tile(ramp, (height // 2, 1)), cv2.COLORMAP_MAGMA)
    bar = np.vstack((strip, np.zeros((height - len(strip), width, 3), np.uint8)))
    scale = height / 64
    near_m = 1 / top_inverse_m
    ticks = [d for d in BAR_TICKS_M if 0.04 <= 1 / d / top_inverse_m <= 0.9]
    labels = [(near_m, f"{near_m:.1f} m")] + [(d, f"{d} m") for d in ticks]
    free_until = width + 4  # labels go near to far; one that would overlap is left out
    for depth, text in labels:
        x = min(width - 1, int(round((1 / depth) / top_inverse_m * (width - 1))))
        (text_w, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        left = int(np.clip(x - text_w // 2, 0, width - text_w))
        if left + text_w + 4 > free_until:
            continue
        free_until = left
        cv2.line(bar, (x, 0), (x, len(strip)), (255, 255, 255), 1)
        cv2.putText(
            bar,
            text,
            (left, height - max(2, height // 10)),
            cv2.FONT_HERSHEY_SIMPLEX,
            scale,
            (255, 255, 255),
            1,
            cv2.LINE_AA,
        )
    return bar


def depth_cloud(depth_m: np.ndarray, camera: PinholeCamera, image: np.ndarray):  # noqa: ANN201 - a PointCloud
    """The organised camera-frame cloud of a depth map (mm), coloured by ``image``."""
    from services.lib.pointcloud.ply import PointCloud

    if camera.width != depth_m.shape[1] or camera.height != depth_m.shape[0]:
        camera = camera.resized(depth_m.shape[1], depth_m.shape[0])
    keep = (depth_m > 0) & (depth_m < CLOUD_MAX_DEPTH_M)
    points = camera.rays() * np.where(keep, depth_m, np.nan)[..., None] * 1000.0
    return PointCloud(
        points=points.reshape(-1, 3).astype(np.float32),
        colors=image.reshape(-1, 3).astype(np.uint8),
        grid_shape=depth_m.shape,
    )


def predict_folder(
    model: DepthModel,
    images: list[Path],
    out_dir: Path,
    *,
    camera: PinholeCamera | None = None,
    clouds: bool = False,
    progress: Progress | None = None,
    shown: Callable[[Path], str] = lambda path: path.name,
) -> list[PredictedImage]:
    """Predict every image of ``images`` into ``out_dir`` (module docstring); clouds need
    the ``camera`` (its K is scaled to each image's size). ``shown``: an image as the
    progress messages name it (its file name; a job gives the name the user uploaded)."""
    import cv2

    from services.depth.data import nominal_K
    from services.lib.pointcloud.ply import write_ply

    say = progress or (lambda fraction, message: None)
    out_dir.mkdir(parents=True, exist_ok=True)
    done = []
    for k, path in enumerate(images):
        image = read_image(path)
        depth, seconds = predict_image(model, image)
        name = path.stem
        depth_path, colour_path = out_dir / f"{name}.png", out_dir / f"{name}.color.png"
        write_depth_png(depth_path, depth)
        cv2.imwrite(str(colour_path), colour_preview(depth))
        cloud_path = None
        if clouds:
            height, width = depth.shape
            lens = camera or PinholeCamera(width, height, nominal_K(width, height))
            cloud_path = out_dir / f"{name}.ply"
            write_ply(
                cloud_path,
                depth_cloud(depth, lens, image),
                comments=("vista depth: camera frame x right, y down, z forward, mm",),
            )
        done.append(
            PredictedImage(
                name,
                path,
                depth_path,
                colour_path,
                cloud_path,
                image.shape[1],
                image.shape[0],
                seconds,
                float(np.median(depth)),
            )
        )
        say(
            (k + 1) / len(images),
            f"image {k + 1}/{len(images)}, {shown(path)}: {seconds * 1000:.0f} ms",
        )
    return done


@dataclass(frozen=True)
class ImageSet:
    """Images to predict and what places their clouds."""

    images: tuple[Path, ...]
    calibration: Path | None
    """A calibration file, or a folder with ``calib.json`` or ``calib_cam_to_cam.txt`` (there
    or in its parent); None: KITTI's camera at the images' size."""


def image_set(folder: Path, calibration: Path | None = None) -> ImageSet:
    """The images of ``folder`` as the command and the job read them: a drive folder's left
    images (``image_02/``, or KITTI raw's ``image_02/data/``), placed by ``calibration`` or
    else the drive's own; or the folder's PNG and JPEG images (or its ``data/``'s), placed
    by ``calibration``. ValueError when there is no image."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such folder")
    drive = (folder / "image_02").is_dir()
    images = image_files(folder / "image_02" if drive else folder)
    if not images:
        raise ValueError(f"{folder}: no PNG or JPEG images")
    return ImageSet(tuple(images), calibration or (folder if drive else None))


@dataclass(frozen=True)
class DepthPrediction:
    images: tuple[PredictedImage, ...]
    """Every image of every set, in order."""
    architecture: str | None
    """The model's, as its metadata says (None for a model without vista's)."""
    width: int
    height: int
    """The model's input size, px."""
    int8_path: Path | None
    """The int8 model predicted with, when asked for."""

    @property
    def mean_seconds(self) -> float:
        return sum(p.seconds for p in self.images) / len(self.images)


def predict_depth(
    sets: list[ImageSet],
    params: PredictParams,
    out_dir: Path,
    *,
    model: Path | None = None,
    threads: int = 2,
    progress: Progress | None = None,
    shown: Callable[[Path], str] = lambda path: path.name,
) -> DepthPrediction:
    """Depth for every image of ``sets`` by the model at ``model`` (None: the one vista
    ships), quantized to int8 first when ``params`` say so (calibrated on up to
    ``CALIBRATION_IMAGES`` of the images, evenly spaced; kept as ``out_dir/model.int8.onnx``).
    The files of the module docstring go to ``out_dir``, a set's to ``out_dir/set-K/`` when
    there are several (their names may repeat). ValueError naming a file it cannot use."""
    say = progress or (lambda fraction, message: None)
    fp32 = network = DepthModel(model or default_model(), threads)
    paths = [path for images in sets for path in images.images]
    int8_path = out_dir / "model.int8.onnx" if params.int8 else None
    if int8_path is not None:
        network = DepthModel(
            quantize_int8(network, _calibration_frames(network, paths), int8_path, operators=True),
            threads,
        )
    done: list[PredictedImage] = []
    for k, images in enumerate(sets):
        before, count = len(done), len(images.images)
        done += predict_folder(
            network,
            list(images.images),
            out_dir if len(sets) == 1 else out_dir / f"set-{k}",
            camera=_camera(images) if params.clouds else None,
            clouds=params.clouds,
            progress=lambda f, m, b=before, n=count: say((b + f * n) / len(paths), m),
            shown=shown,
        )
    architecture = fp32.spec.metadata.get("architecture")
    return DepthPrediction(tuple(done), architecture, fp32.spec.width, fp32.spec.height, int8_path)


def _calibration_frames(model: DepthModel, paths: list[Path]) -> np.ndarray:
    """(N, H, W, 3) uint8: every len(paths) // ``CALIBRATION_IMAGES``-th image at the
    model's size, what int8 quantization calibrates on."""
    chosen = paths[:: max(1, len(paths) // CALIBRATION_IMAGES)]
    return np.stack([resize_for(model, read_image(path)) for path in chosen])


def _camera(images: ImageSet) -> PinholeCamera | None:
    """The camera of ``images``' calibration at the size of their first image."""
    if images.calibration is None:
        return None
    first = read_image(images.images[0])
    size = (first.shape[1], first.shape[0])
    if images.calibration.is_file():
        return read_calibration_file(images.calibration, size)
    return read_calibration(images.calibration, size)
