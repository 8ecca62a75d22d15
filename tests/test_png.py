"""The fast 8-bit grey PNG path (``services.lib.png``): the same pixels as OpenCV on every
row filter, and every other or damaged file left to OpenCV."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from services.lib.png import decode_grey8
from services.odometry.camera import FloorCamera
from services.odometry.frames import read_frame

HEIGHT, WIDTH = 23, 37


def _chunk(kind: bytes, body: bytes, crc: int | None = None) -> bytes:
    crc = zlib.crc32(kind + body) if crc is None else crc
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def _filtered(image: np.ndarray, kinds: np.ndarray) -> bytes:
    """Each row under its filter type (PNG's definitions, from the original pixels; a
    type PNG does not define is written unfiltered)."""
    pixels = image.astype(np.int64)
    up = np.vstack([np.zeros((1, pixels.shape[1]), np.int64), pixels[:-1]])
    left = np.hstack([np.zeros((pixels.shape[0], 1), np.int64), pixels[:, :-1]])
    corner = np.hstack([np.zeros((pixels.shape[0], 1), np.int64), up[:, :-1]])
    guess = left + up - corner
    to_left, to_up, to_corner = abs(guess - left), abs(guess - up), abs(guess - corner)
    paeth = np.where(
        (to_left <= to_up) & (to_left <= to_corner), left, np.where(to_up <= to_corner, up, corner)
    )
    predicted = np.stack([0 * pixels, left, up, (left + up) // 2, paeth])
    rows = (pixels - predicted[np.where(kinds < 5, kinds, 0), np.arange(len(kinds))]) % 256
    return np.hstack([kinds[:, None], rows]).astype(np.uint8).tobytes()


def _png(
    image: np.ndarray,
    *,
    kinds: np.ndarray | None = None,
    header: tuple[int, int, int] = (8, 0, 0),
    extra: bytes = b"",
    idat_parts: int = 3,
    crc_of_data: int | None = None,
    end: bool = True,
) -> bytes:
    """A PNG written by hand: ``kinds`` the rows' filter types (all five in turn),
    ``header`` (bit depth, colour type, interlace), ``extra`` chunks after the header,
    the image data split over ``idat_parts`` chunks (the last one's CRC replaced by
    ``crc_of_data`` if given)."""
    kinds = np.arange(image.shape[0]) % 5 if kinds is None else kinds
    depth, colour, interlace = header
    ihdr = struct.pack(">IIBBBBB", image.shape[1], image.shape[0], depth, colour, 0, 0, interlace)
    data = zlib.compress(_filtered(image, kinds))
    cuts = np.linspace(0, len(data), idat_parts + 1).astype(int)
    parts = [data[a:b] for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    idats = b"".join(
        _chunk(b"IDAT", part, crc_of_data if i == len(parts) - 1 else None)
        for i, part in enumerate(parts)
    )
    tail = _chunk(b"IEND", b"") if end else b""
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + extra + idats + tail


@pytest.fixture
def image() -> np.ndarray:
    rng = np.random.default_rng(3)
    smooth = np.add.outer(np.arange(HEIGHT) * 9, np.arange(WIDTH) * 5) % 256
    return ((smooth + rng.integers(0, 60, (HEIGHT, WIDTH))) % 256).astype(np.uint8)


def test_every_row_filter_decodes_to_the_pixels_opencv_reads(image: np.ndarray) -> None:
    data = _png(image, extra=_chunk(b"tEXt", b"Software\x00vista"))
    opencv = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(opencv, image)  # the hand-made file is a valid PNG
    decoded = decode_grey8(data)
    assert decoded is not None and decoded.dtype == np.uint8
    np.testing.assert_array_equal(decoded, image)


@pytest.mark.parametrize("width", [WIDTH, 1, 2, 3, 4])
def test_rows_filtered_by_average_in_runs_of_any_length_decode_to_the_pixels(width: int) -> None:
    """Four rows in a row filtered by average are undone together: runs of 1–9 such rows
    between other filters, and every row, give the same pixels as OpenCV reads."""
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (HEIGHT, width), dtype=np.uint8)
    runs = np.concatenate([[3] * k + [k % 3] for k in range(1, 10)])[:HEIGHT]
    for kinds in (np.full(HEIGHT, 3), runs, np.roll(runs, 2)):
        data = _png(image, kinds=kinds)
        opencv = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
        np.testing.assert_array_equal(opencv, image)
        np.testing.assert_array_equal(decode_grey8(data), image)


def test_pngs_written_by_opencv_decode_the_same(image: np.ndarray) -> None:
    for level in (0, 1, 9):
        ok, encoded = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, level])
        assert ok
        np.testing.assert_array_equal(decode_grey8(encoded.tobytes()), image)


@pytest.mark.parametrize(
    "change",
    [
        {"header": (8, 2, 0)},  # RGB
        {"header": (16, 0, 0)},
        {"header": (8, 0, 1)},  # interlaced
        {"extra": _chunk(b"gAMA", struct.pack(">I", 45455))},  # OpenCV may correct it
        {"crc_of_data": 1},  # damaged
        {"kinds": np.full(HEIGHT, 5)},  # no such filter
        {"end": False},  # truncated
    ],
    ids=["rgb", "16-bit", "interlaced", "gamma", "bad-crc", "bad-filter", "truncated"],
)
def test_other_or_damaged_files_are_left_to_opencv(image: np.ndarray, change: dict) -> None:
    assert decode_grey8(_png(image, **change)) is None


def test_a_frame_not_on_the_fast_path_is_still_read_grey_by_opencv(tmp_path: Path) -> None:
    camera = FloorCamera.thesis(WIDTH, HEIGHT)
    colour = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    colour[..., 1] = 200  # green: grey 117 by OpenCV's weights
    cv2.imwrite(str(tmp_path / "colour.png"), colour)
    np.testing.assert_array_equal(read_frame(tmp_path / "colour.png", camera), 117)
    (tmp_path / "damaged.png").write_bytes(_png(colour[..., 0], crc_of_data=1))
    with pytest.raises(ValueError, match="not an image OpenCV can read"):
        read_frame(tmp_path / "damaged.png", camera)


def test_a_real_camera_frame_in_grey_decodes_as_opencv_reads_it() -> None:
    """A KITTI camera frame (not this project's simulator): as stored (RGB) it is left to
    OpenCV; turned grey and written by OpenCV, it takes the fast path to the same pixels."""
    from services.odometry.bench import KITTI_FRAME

    if not KITTI_FRAME.is_file():
        pytest.skip("../shared/data's KITTI raw drive is not here")
    data = KITTI_FRAME.read_bytes()
    assert decode_grey8(data) is None
    grey = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    ok, encoded = cv2.imencode(".png", grey)
    assert ok
    np.testing.assert_array_equal(decode_grey8(encoded.tobytes()), grey)
