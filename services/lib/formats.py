"""Checks of the file formats several services share, as artifact-kind ``inspect`` hooks
(``contract.artifacts.Inspect``): PLY clouds and meshes, JSON, PNG, GLB, camera images,
KITTI depth maps, ONNX models, and any file. Each reads the file as a job will and refuses
with a sentence (``ArtifactRefused``) what a job could not read."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import TypeVar

from contract.artifacts import ArtifactRefused, Inspected
from contract.vocabulary import ONNX_MEDIA_TYPE
from services.lib.pointcloud.ply import PLY_MEDIA_TYPE

Found = TypeVar("Found")
MAX_JSON_BYTES = 256 * 1024 * 1024
MAX_IMAGE_BYTES = 256 * 1024 * 1024
MAX_MODEL_BYTES = 512 * 1024 * 1024
"""onnx, onnxruntime and the check each hold a copy (protobuf's own limit is 2 GiB)."""
JSON_MEDIA_TYPE = "application/json"
PNG_MEDIA_TYPE = "image/png"
GLB_MEDIA_TYPE = "model/gltf-binary"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
JPEG_MAGIC = b"\xff\xd8\xff"


def text_of(exc: Exception) -> str:
    """An error's sentence as it can be sent: a tar member's name that is not UTF-8 comes
    with surrogates (tarfile's ``surrogateescape``), which no JSON response can encode."""
    return str(exc).encode("utf-8", "backslashreplace").decode("utf-8")


def checked(read: Callable[[Path], Found], path: Path, what: str) -> Found:
    """``read(path)`` as a kind's check: its refusal (a ``ValueError``) is "is not {what}:
    …"."""
    try:
        return read(path)
    except ValueError as exc:
        raise ArtifactRefused(f"is not {what}: {text_of(exc)}") from exc


def limit_size(path: Path, limit_bytes: int, what: str) -> None:
    if path.stat().st_size > limit_bytes:
        raise ArtifactRefused(
            f"is larger than the {limit_bytes // 2**20} MiB {what} are limited to",
            too_large=True,
        )


def _head(path: Path, size: int = 8) -> bytes:
    with open(path, "rb") as handle:
        return handle.read(size)


def is_ply(head: bytes) -> bool:
    return head.startswith((b"ply\n", b"ply\r\n"))


def _ply(path: Path, *, mesh: bool) -> Inspected:
    from services.lib.pointcloud.ply import PlyError, read_mesh, validate_ply

    what = "triangle mesh" if mesh else "point cloud"
    if not is_ply(_head(path)):
        others = "" if mesh else ", nor is it a PCD, LAS/LAZ, E57, XYZ/ASC or PTS cloud"
        raise ArtifactRefused(
            f"must be a PLY {what}, but it does not start with the PLY magic line 'ply'{others}"
        )
    try:
        info = validate_ply(path)
        faces = len(read_mesh(path)[1]) if mesh else None
    except PlyError as exc:
        raise ArtifactRefused(f"is not a valid PLY {what}: {exc}") from exc
    meta = asdict(info)
    meta["grid_shape"] = list(info.grid_shape) if info.grid_shape else None
    if faces is not None:
        meta["faces"] = faces
    return Inspected(PLY_MEDIA_TYPE, {"ply": meta})


def inspect_cloud(path: Path, media_type: str, units: str | None = None) -> Inspected:
    """A point cloud: vista's PLY checked for header, element sizes and finite
    coordinates; any other cloud format a scanner writes (``scanner.sniff``) converted to
    it, in millimetres, the source's format and unit in the metadata."""
    from services.lib.pointcloud.reader import convert_isolated
    from services.lib.pointcloud.scanner import ScannerFormatError, sniff

    if sniff(path) in (None, "ply") and units in (None, "mm"):
        return _ply(path, mesh=False)
    out = path.with_suffix(".converted.part")
    try:
        source = convert_isolated(path, out, units=units)
        found = _ply(out, mesh=False)
    except (ScannerFormatError, ArtifactRefused) as exc:
        out.unlink(missing_ok=True)
        raise ArtifactRefused(str(exc)) from exc
    return Inspected(found.media_type, {**found.meta, "source": source}, out)


def inspect_mesh(path: Path, media_type: str) -> Inspected:
    """A PLY triangle mesh: a point cloud with faces that index it."""
    return _ply(path, mesh=True)


STL_MEDIA_TYPE = "model/stl"
NOMINAL_MEDIA_TYPES = {
    "stl": STL_MEDIA_TYPE,
    "obj": "model/obj",
    "ply": PLY_MEDIA_TYPE,
    "gltf": "model/gltf+json",
    "glb": GLB_MEDIA_TYPE,
    "step": "model/step",
}
MAX_LISTED_REGIONS = 200
"""A nominal's regions named in its metadata (a STEP may have thousands of faces)."""


def inspect_nominal(path: Path, media_type: str, units: str | None = None) -> Inspected:
    """A part's nominal model read as a comparison will read it (STL, OBJ, PLY mesh,
    glTF/GLB, STEP), its regions, closure, orientation, border, area and bounds reported (a
    nominal need not be closed); in millimetres: a file in other units (``units``, or a
    glTF's metres) is kept as an STL in mm beside it, its regions as its solids."""
    from services.lib.pointcloud.nominal import NominalError, read_nominal
    from services.lib.pointcloud.scanner import UNITS_MM
    from services.lib.pointcloud.stl import mesh_report, write_stl

    try:
        nominal = read_nominal(path, None if units is None else UNITS_MM[units])
    except (NominalError, OSError) as exc:
        raise ArtifactRefused(
            "is not a nominal model vista reads (STL, OBJ, PLY mesh, glTF/GLB or STEP): "
            f"{text_of(exc)}"
        ) from exc
    replacement, stored_type = None, NOMINAL_MEDIA_TYPES[nominal.format]
    if nominal.scale_to_mm != 1.0 or nominal.format in ("gltf", "glb"):
        replacement, stored_type = path.with_name(path.name + ".mm.stl"), STL_MEDIA_TYPE
        several = len(nominal.regions) > 1
        write_stl(replacement, nominal.mesh, binary=not several,
                  region_of_face=nominal.region_of_face, regions=nominal.regions)  # fmt: skip
    report = asdict(mesh_report(nominal.mesh))
    meta = {
        "format": nominal.format,
        "units": "mm",
        "source_units": units or ("m" if nominal.format in ("gltf", "glb") else "mm"),
        "regions": list(nominal.regions[:MAX_LISTED_REGIONS]),
        "region_count": len(nominal.regions),
        **report,
    }
    return Inspected(stored_type, {"nominal": meta}, replacement)


def inspect_json(path: Path, media_type: str) -> Inspected:
    """Parsed whole, once its nesting is known to be at most ``MAX_JSON_DEPTH`` (Python's
    parser recurses once per level: 200 000 brackets would exhaust the stack)."""
    from services.lib.archive import MAX_JSON_DEPTH, JsonTooDeep, parse_json

    limit_size(path, MAX_JSON_BYTES, "JSON artifacts")
    try:
        parse_json(path.read_bytes())
    except JsonTooDeep as exc:
        raise ArtifactRefused(f"{exc}; vista reads JSON up to {MAX_JSON_DEPTH} levels") from exc
    except ValueError as exc:
        raise ArtifactRefused(f"is not valid JSON: {exc}") from exc
    return Inspected(JSON_MEDIA_TYPE)


def inspect_png(path: Path, media_type: str) -> Inspected:
    """A PNG by its signature (a figure: vista only serves it back)."""
    if not _head(path).startswith(PNG_MAGIC):
        raise ArtifactRefused("does not start with the PNG signature")
    return Inspected(PNG_MEDIA_TYPE)


def inspect_glb(path: Path, media_type: str) -> Inspected:
    """A binary glTF by its magic (a scene: vista only serves it back)."""
    if not _head(path).startswith(b"glTF"):
        raise ArtifactRefused("does not start with the GLB magic 'glTF'")
    return Inspected(GLB_MEDIA_TYPE)


def png_header(path: Path) -> tuple[int, int, int, int] | None:
    """A PNG's (width, height, bit depth, colour type) from its IHDR chunk."""
    head = _head(path, 26)
    if len(head) < 26 or not head.startswith(PNG_MAGIC) or head[12:16] != b"IHDR":
        return None
    return (
        int.from_bytes(head[16:20], "big"),
        int.from_bytes(head[20:24], "big"),
        head[24],
        head[25],
    )


def _decodable(path: Path) -> None:
    """The image decoded once, as the jobs will read it (under the archives' pixel limit)."""
    from services.lib.archive import ArchiveError, decode_image

    limit_size(path, MAX_IMAGE_BYTES, "images")
    try:
        decode_image("", path.read_bytes())
    except ArchiveError as exc:
        raise ArtifactRefused(str(exc).strip()) from exc


def inspect_image(path: Path, media_type: str) -> Inspected:
    """A camera image, PNG or JPEG, decoded once."""
    if _head(path).startswith(JPEG_MAGIC):
        _decodable(path)
        return Inspected("image/jpeg")
    header = png_header(path)
    if header is None:
        raise ArtifactRefused("is neither a PNG nor a JPEG image")
    _decodable(path)
    return Inspected(PNG_MEDIA_TYPE, {"width": header[0], "height": header[1]})


def inspect_depth_png(path: Path, media_type: str) -> Inspected:
    """A depth map in KITTI's convention: a 16-bit grey PNG (metres × 256)."""
    header = png_header(path)
    if header is None:
        raise ArtifactRefused("does not start with the PNG signature")
    width, height, bits, colour = header
    if bits != 16 or colour != 0:
        raise ArtifactRefused(
            f"is a {bits}-bit PNG of colour type {colour}; a depth map is 16-bit grey "
            "(KITTI: metres × 256)"
        )
    _decodable(path)
    return Inspected(PNG_MEDIA_TYPE, {"width": width, "height": height})


def inspect_model(path: Path, media_type: str) -> Inspected:
    """vista's metadata read, and the model loaded by onnxruntime as a job would: a custom
    operator or weights in external files are refused here, not in the job."""
    from services.lib.nn.onnx_io import check_runnable, read_model

    limit_size(path, MAX_MODEL_BYTES, "models")
    try:
        metadata = read_model(path).metadata
        check_runnable(path)
    except ValueError as exc:
        reason = text_of(exc).replace(f"{path}: ", "")
        raise ArtifactRefused(f"is not a model vista can run: {reason}") from exc
    meta = {"architecture": metadata.get("architecture"), "metrics": metadata.get("metrics")}
    return Inspected(ONNX_MEDIA_TYPE, meta)


_BY_MEDIA_TYPE = {
    PLY_MEDIA_TYPE: inspect_cloud,
    JSON_MEDIA_TYPE: inspect_json,
    PNG_MEDIA_TYPE: inspect_png,
    GLB_MEDIA_TYPE: inspect_glb,
}


def inspect_any(path: Path, media_type: str) -> Inspected:
    """Any file, kept as declared; a PLY (by its magic line) or a declared JSON, PNG or GLB
    is still checked as one, so what is served as such can be read as such."""
    if is_ply(_head(path)):
        return inspect_cloud(path, media_type)
    check = _BY_MEDIA_TYPE.get(media_type)
    return check(path, media_type) if check else Inspected(media_type)
