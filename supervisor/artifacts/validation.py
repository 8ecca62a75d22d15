"""Checking an uploaded file before it is kept: its content must be what its kind needs,
whatever media type was declared (a PLY is recognised by its magic line)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from contract.vocabulary import ONNX_MEDIA_TYPE
from services.pointcloud.ply import PLY_MEDIA_TYPE, PlyError, read_mesh, validate_ply
from supervisor.artifacts.kinds import ARTIFACT_KINDS, Format
from supervisor.problems import Problem

MAX_JSON_BYTES = 256 * 1024 * 1024
MAX_TUM_BYTES = 256 * 1024 * 1024
MAX_IMAGE_BYTES = 256 * 1024 * 1024
MAX_MODEL_BYTES = 512 * 1024 * 1024
"""onnx, onnxruntime and the check each hold a copy (protobuf's own limit is 2 GiB)."""
_MEDIA_TYPE_OF: dict[Format, str] = {
    "ply": PLY_MEDIA_TYPE,
    "ply-mesh": PLY_MEDIA_TYPE,
    "json": "application/json",
    "png": "image/png",
    "glb": "model/gltf-binary",
    "onnx": ONNX_MEDIA_TYPE,
    "tum": "text/plain",
}
_FORMAT_OF_MEDIA_TYPE: dict[str, Format] = {
    PLY_MEDIA_TYPE: "ply",
    "application/json": "json",
    "image/png": "png",
    "model/gltf-binary": "glb",
}
_MAGIC: dict[Format, tuple[bytes, str]] = {
    "png": (b"\x89PNG\r\n\x1a\n", "the PNG signature"),
    "glb": (b"glTF", "the GLB magic 'glTF'"),
}


def is_ply(head: bytes) -> bool:
    return head.startswith((b"ply\n", b"ply\r\n"))


def validate_upload(path: Path, *, media_type: str, name: str, kind: str) -> tuple[str, dict]:
    """The media type to keep and the metadata learned from the file; raises a 422
    Problem naming what is wrong if the content is not what ``kind`` needs."""
    with open(path, "rb") as handle:
        head = handle.read(8)
    required = ARTIFACT_KINDS[kind].format
    declared = _FORMAT_OF_MEDIA_TYPE.get(media_type)
    form = required or ("ply" if is_ply(head) else declared)
    if form in ("ply", "ply-mesh"):
        return PLY_MEDIA_TYPE, {"ply": _ply_meta(path, name, kind, mesh=form == "ply-mesh")}
    if form == "archive":
        return _sequence_meta(path, name, kind)
    if form == "drive":
        return _drive_meta(path, name, kind)
    if form == "lidar":
        return _lidar_meta(path, name, kind)
    if form == "image":
        return _image_meta(path, head, name, kind)
    if form == "depth-png":
        return "image/png", _depth_png_meta(path, name, kind)
    if form == "json":
        _check_json(path, name, kind)
    elif form == "onnx":
        return _MEDIA_TYPE_OF[form], _model_meta(path, name, kind)
    elif form == "tum":
        _check_tum(path, name, kind)
    elif form in _MAGIC:
        magic, called = _MAGIC[form]
        if not head.startswith(magic):
            raise Problem(422, f"{name} (kind={kind}) does not start with {called}.")
    return (_MEDIA_TYPE_OF[form] if form else media_type), {}


def _ply_meta(path: Path, name: str, kind: str, *, mesh: bool) -> dict:
    what = "triangle mesh" if mesh else "point cloud"
    with open(path, "rb") as handle:
        if not is_ply(handle.read(5)):
            raise Problem(
                422,
                f"{name} (kind={kind}) must be a PLY {what}, but it does not start with the "
                "PLY magic line 'ply'.",
            )
    try:
        info = validate_ply(path)
        faces = len(read_mesh(path)[1]) if mesh else None
    except PlyError as exc:
        raise Problem(422, f"{name} is not a valid PLY {what}: {exc}.") from exc
    meta = asdict(info)
    meta["grid_shape"] = list(info.grid_shape) if info.grid_shape else None
    if faces is not None:
        meta["faces"] = faces
    return meta


def _check_json(path: Path, name: str, kind: str) -> None:
    """Parsed whole, once its nesting is known to be at most ``MAX_JSON_DEPTH`` (Python's
    parser recurses once per level: 200 000 brackets would exhaust the stack)."""
    from services.archive import MAX_JSON_DEPTH, JsonTooDeep, parse_json

    if path.stat().st_size > MAX_JSON_BYTES:
        raise Problem(413, f"JSON artifacts are limited to {MAX_JSON_BYTES // 2**20} MiB.")
    try:
        parse_json(path.read_bytes())
    except JsonTooDeep as exc:
        raise Problem(
            422, f"{name} (kind={kind}) {exc}; vista reads JSON up to {MAX_JSON_DEPTH} levels."
        ) from exc
    except ValueError as exc:
        raise Problem(422, f"{name} (kind={kind}) is not valid JSON: {exc}.") from exc


def _text(exc: Exception) -> str:
    """An error's sentence as it can be sent: a tar member's name that is not UTF-8 comes
    with surrogates (tarfile's ``surrogateescape``), which no JSON response can encode."""
    return str(exc).encode("utf-8", "backslashreplace").decode("utf-8")


def _sequence_meta(path: Path, name: str, kind: str) -> tuple[str, dict]:
    from services.odometry.sequence import SequenceError, inspect_sequence

    try:
        found = inspect_sequence(path)
    except SequenceError as exc:
        raise Problem(422, f"{name} (kind={kind}) is not a frame sequence: {_text(exc)}.") from exc
    meta = {
        "frames": len(found.frames),
        "camera": found.camera.document(),
        "truth": found.truth_member is not None,
    }
    return found.media_type, meta


def _drive_meta(path: Path, name: str, kind: str) -> tuple[str, dict]:
    from services.archive import ArchiveError
    from services.depth.drive_archive import inspect_drive

    try:
        found = inspect_drive(path)
    except ArchiveError as exc:
        raise Problem(422, f"{name} (kind={kind}) is not a drive: {_text(exc)}.") from exc
    meta = {
        "frames": found.frames,
        "stereo": found.stereo,
        "depth": found.depth,
        "scans": found.scans,
        "poses": found.poses,
    }
    return found.media_type, meta


def _lidar_meta(path: Path, name: str, kind: str) -> tuple[str, dict]:
    from services.archive import ArchiveError
    from services.tracking.lidar_archive import inspect_lidar

    try:
        found = inspect_lidar(path)
    except ArchiveError as exc:
        raise Problem(422, f"{name} (kind={kind}) is not a LiDAR sequence: {_text(exc)}.") from exc
    meta = {
        "frames": found.frames,
        "labels": found.labels,
        "tracks": found.tracks,
        "poses": found.poses,
    }
    return found.media_type, meta


JPEG_MAGIC = b"\xff\xd8\xff"


def _png_header(path: Path) -> tuple[int, int, int, int] | None:
    """A PNG's (width, height, bit depth, colour type) from its IHDR chunk."""
    with open(path, "rb") as handle:
        head = handle.read(26)
    if len(head) < 26 or not head.startswith(_MAGIC["png"][0]) or head[12:16] != b"IHDR":
        return None
    return (
        int.from_bytes(head[16:20], "big"),
        int.from_bytes(head[20:24], "big"),
        head[24],
        head[25],
    )


def _decodable(path: Path, name: str, kind: str) -> None:
    """The image decoded once, as the jobs will read it (under the archives' pixel limit)."""
    from services.archive import ArchiveError, decode_image

    if path.stat().st_size > MAX_IMAGE_BYTES:
        raise Problem(413, f"Images are limited to {MAX_IMAGE_BYTES // 2**20} MiB.")
    try:
        decode_image(name, path.read_bytes())
    except ArchiveError as exc:
        raise Problem(422, f"{name} (kind={kind}){str(exc).removeprefix(name)}.") from exc


def _image_meta(path: Path, head: bytes, name: str, kind: str) -> tuple[str, dict]:
    if head.startswith(JPEG_MAGIC):
        _decodable(path, name, kind)
        return "image/jpeg", {}
    header = _png_header(path)
    if header is None:
        raise Problem(422, f"{name} (kind={kind}) is neither a PNG nor a JPEG image.")
    _decodable(path, name, kind)
    return "image/png", {"width": header[0], "height": header[1]}


def _depth_png_meta(path: Path, name: str, kind: str) -> dict:
    header = _png_header(path)
    if header is None:
        raise Problem(422, f"{name} (kind={kind}) does not start with the PNG signature.")
    width, height, bits, colour = header
    if bits != 16 or colour != 0:
        raise Problem(
            422,
            f"{name} (kind={kind}) is a {bits}-bit PNG of colour type {colour}; a depth map is "
            "16-bit grey (KITTI: metres × 256).",
        )
    _decodable(path, name, kind)
    return {"width": width, "height": height}


def _model_meta(path: Path, name: str, kind: str) -> dict:
    """vista's metadata read, and the model loaded by onnxruntime as a job would: a custom
    operator or weights in external files are refused here, not in the job."""
    from services.nn.onnx_io import check_runnable, read_model

    if path.stat().st_size > MAX_MODEL_BYTES:
        raise Problem(413, f"Models are limited to {MAX_MODEL_BYTES // 2**20} MiB.")
    try:
        metadata = read_model(path).metadata
        check_runnable(path)
    except ValueError as exc:
        reason = _text(exc).replace(f"{path}: ", "")
        raise Problem(422, f"{name} (kind={kind}) is not a model vista can run: {reason}.") from exc
    return {"architecture": metadata.get("architecture"), "metrics": metadata.get("metrics")}


def _check_tum(path: Path, name: str, kind: str) -> None:
    from services.odometry.tum import parse_tum

    if path.stat().st_size > MAX_TUM_BYTES:
        raise Problem(413, f"TUM trajectories are limited to {MAX_TUM_BYTES // 2**20} MiB.")
    try:
        text = path.read_text(encoding="utf-8")
        parse_tum(text, name)
    except ValueError as exc:  # UnicodeDecodeError too
        raise Problem(422, f"{name} (kind={kind}) is not a TUM trajectory: {exc}.") from exc
