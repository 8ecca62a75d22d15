"""A drive in one file: a zip or tar of a KITTI-layout drive folder (``kitti.read_drive``) —
``image_02/`` (or ``image_02/data/``), and as known ``image_03/``, ``depth/`` (or
``proj_depth/groundtruth/image_02/``), ``velodyne/`` (or ``velodyne_points/data/``: LiDAR
scans, ``.bin``), ``calib.json`` or ``calib_cam_to_cam.txt`` (with
``calib_velo_to_cam.txt`` for the scans) and ``poses.txt``, under any one top folder of the
archive.

Members are written under names of vista's choosing (the role's folder and the file's own
base name, which must be plain: letters, digits, ``_``, ``-``, ``.``), never by the archive's
paths; what the archive expands to is checked as it is read (``services.lib.archive``). At upload
every image is decoded once: one OpenCV cannot read, or a depth map that is not one 16-bit
channel, is refused naming it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath

import numpy as np

from contract.artifacts import Inspected
from services.depth.drive import IMAGE_SUFFIXES
from services.lib.archive import (
    ArchiveError,
    Member,
    decode_image,
    media_type,
    opened,
    read_in_order,
    read_member,
)
from services.lib.formats import checked

HINT = "pack a drive folder with `tar czf drive.tar.gz -C DRIVE .` (image_02/ inside)"
SCAN_SUFFIXES = (".bin",)
SCAN_POINT_BYTES = 16
MAX_MEMBER_BYTES = {"image": 256 << 20, "text": 64 << 20}
SCAN_ROLES = {"velodyne": "velodyne", "velodyne_points/data": "velodyne"}
ROLES = {
    "image_02": "image_02",
    "image_02/data": "image_02",
    "image_03": "image_03",
    "image_03/data": "image_03",
    "depth": "depth",
    "proj_depth/groundtruth/image_02": "depth",
}
TEXT_FILES = ("calib.json", "calib_cam_to_cam.txt", "calib_velo_to_cam.txt", "poses.txt")
PLAIN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class DriveArchive:
    form: str
    files: dict[str, str]
    """Member name → where it goes, relative to the drive folder."""
    frames: int
    stereo: bool
    depth: bool
    scans: bool
    poses: bool
    media_type: str


def _plan(form: str, members: list[Member]) -> DriveArchive:
    roots = set()
    for member in members:
        parts = PurePosixPath(member.name).parts
        if "image_02" in parts[:-1]:
            roots.add(
                PurePosixPath(*parts[: parts.index("image_02")])
                if parts.index("image_02")
                else PurePosixPath(".")
            )
    if not roots:
        raise ArchiveError("no image_02/ folder of left-camera images in the archive")
    if len(roots) > 1:
        shown = ", ".join(sorted(str(r) for r in roots)[:3])
        raise ArchiveError(
            f"image_02/ appears under {len(roots)} folders ({shown}): one drive per archive"
        )
    root = roots.pop()
    files: dict[str, str] = {}
    for member in members:
        path = PurePosixPath(member.name)
        if root != PurePosixPath(".") and not path.is_relative_to(root):
            continue
        inside = path.relative_to(root) if root != PurePosixPath(".") else path
        folder, name = str(inside.parent), inside.name
        if folder == "." and name in TEXT_FILES:
            files[member.name] = name
        elif (folder in ROLES and Path(name).suffix.lower() in IMAGE_SUFFIXES) or (
            folder in SCAN_ROLES and Path(name).suffix.lower() in SCAN_SUFFIXES
        ):
            if not PLAIN.match(name):
                raise ArchiveError(
                    f"{member.name}: file names must be plain (letters, digits, _ - .)"
                )
            if folder in SCAN_ROLES and member.size % SCAN_POINT_BYTES:
                raise ArchiveError(
                    f"{member.name}: {member.size:,} bytes is not a scan of whole "
                    f"{SCAN_POINT_BYTES}-byte points (x, y, z, reflectance as float32)"
                )
            files[member.name] = f"{ROLES.get(folder) or SCAN_ROLES[folder]}/{name}"
    targets = list(files.values())
    frames = sum(t.startswith("image_02/") for t in targets)
    if frames == 0:
        raise ArchiveError("no PNG or JPEG image in image_02/")
    if not any(t in ("calib.json", "calib_cam_to_cam.txt") for t in targets):
        raise ArchiveError("no calib.json or calib_cam_to_cam.txt beside image_02/")
    if len(set(targets)) != len(targets):
        raise ArchiveError("two members land on the same file (image_02/ and image_02/data/ both?)")
    return DriveArchive(
        form,
        files,
        frames,
        stereo=any(t.startswith("image_03/") for t in targets),
        depth=any(t.startswith("depth/") for t in targets),
        scans=any(t.startswith("velodyne/") for t in targets),
        poses="poses.txt" in targets,
        media_type="",
    )


def _check_images(form: str, archive: object, members: list[Member], plan: DriveArchive) -> None:
    """Every image decoded once, in one pass in the archive's order; the depth maps must be
    KITTI's (one 16-bit channel, metres × 256)."""
    images = {
        name: MAX_MEMBER_BYTES["image"]
        for name, target in plan.files.items()
        if target not in TEXT_FILES and not target.startswith("velodyne/")
    }
    for member, data in read_in_order(form, archive, members, images):
        image = decode_image(member.name, data)
        if plan.files[member.name].startswith("depth/") and (
            image.dtype != np.uint16 or image.ndim != 2
        ):
            raise ArchiveError(
                f"{member.name}: a depth map is one 16-bit channel (KITTI: metres × 256), not "
                f"{image.dtype} × {1 if image.ndim == 2 else image.shape[2]}"
            )


def inspect_drive(path: Path) -> DriveArchive:
    """What the archive holds, its images decoded once, nothing extracted; ArchiveError
    naming the problem."""
    with opened(path, HINT) as (form, members, archive):
        plan = _plan(form, members)
        _check_images(form, archive, members, plan)
    return replace(plan, media_type=media_type(path, form))


def extract_drive(path: Path, out_dir: Path) -> DriveArchive:
    """The archive written as a drive folder at ``out_dir`` (read in the archive's order: a
    compressed tar is one stream)."""
    with opened(path, HINT) as (form, members, archive):
        plan = _plan(form, members)
        for member in members:
            target = plan.files.get(member.name)
            if target is None:
                continue
            limit = MAX_MEMBER_BYTES["text" if target in TEXT_FILES else "image"]
            destination = out_dir / target
            destination.parent.mkdir(parents=True, exist_ok=True)
            destination.write_bytes(read_member(form, archive, member, limit))
    return plan


def inspect_drive_artifact(path: Path, declared: str) -> Inspected:
    """The ``drive`` kind's check (``contract.artifacts.Inspect``): the archive planned as
    the depth jobs read it."""
    found = checked(inspect_drive, path, "a drive")
    kept = ("frames", "stereo", "depth", "scans", "poses")
    return Inspected(found.media_type, {name: getattr(found, name) for name in kept})
