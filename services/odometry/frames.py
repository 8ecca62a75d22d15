"""A sequence's frames: the PNG files of a folder, in name order, read as grey images of
the size its camera says — decoded ahead of their use on a thread of their own."""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from services.lib.png import decode_grey8
from services.odometry.camera import FloorCamera

READ_AHEAD = 8
"""Frames decoded before they are asked for (a 640 × 480 grey frame is 0.3 MB)."""


def frame_files(folder: Path) -> list[Path]:
    """The frames in name order; ValueError when there are fewer than two."""
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder of frames")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png")
    if len(files) < 2:
        raise ValueError(f"{folder}: needs at least 2 PNG frames, found {len(files)}")
    return files


def read_frame(path: Path, camera: FloorCamera) -> np.ndarray:
    """One frame, grey (an 8-bit grey PNG on the fast path, any other through OpenCV);
    ValueError when neither can read it or its size is not the camera's."""
    data = path.read_bytes()
    image = decode_grey8(data)
    if image is None:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError(f"{path}: not an image OpenCV can read")
    if image.shape != (camera.height, camera.width):
        raise ValueError(
            f"{path}: {image.shape[1]} × {image.shape[0]} pixels, but camera.json says "
            f"{camera.width} × {camera.height}"
        )
    return image


def read_frames(
    files: list[Path], camera: FloorCamera, *, ahead: bool = True
) -> Iterator[np.ndarray]:
    """The frames in order. ``ahead``: each decoded while the ones before it are worked
    on, on a reader thread (libdeflate, the compiled filter pass and OpenCV let go of the
    interpreter) — for a consumer that leaves a core free; else each decoded in the
    consumer's thread when asked for (with every core busy already, a reader thread only
    adds switches: odometry on two parts of a run, one per core, ran 7 % faster without).
    An unreadable frame raises where it is reached; a reader left early (the consumer
    failed or stopped) ends with the generator."""
    if not ahead:
        return (read_frame(path, camera) for path in files)
    return _read_ahead(files, camera)


def _read_ahead(files: list[Path], camera: FloorCamera) -> Iterator[np.ndarray]:
    ready: queue.Queue = queue.Queue(READ_AHEAD)
    stop = threading.Event()

    def read() -> None:
        for path in files:
            try:
                item = read_frame(path, camera)
            except ValueError as exc:
                item = exc
            while not stop.is_set():
                try:
                    ready.put(item, timeout=0.1)
                    break
                except queue.Full:
                    continue
            if stop.is_set() or isinstance(item, ValueError):
                return

    reader = threading.Thread(target=read, name="frame-reader", daemon=True)
    reader.start()
    try:
        for _ in files:
            item = ready.get()
            if isinstance(item, ValueError):
                raise item
            yield item
    finally:
        stop.set()
        reader.join()


def read_frames_at_once(files: list[Path], camera: FloorCamera, threads: int) -> list[np.ndarray]:
    """``files`` decoded on ``threads`` threads, in their order."""
    with ThreadPoolExecutor(max(1, threads)) as pool:
        return list(pool.map(lambda path: read_frame(path, camera), files))
