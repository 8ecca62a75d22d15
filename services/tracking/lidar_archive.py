"""A LiDAR sequence in one file: a zip or tar (plain, gzip, bzip2 or xz) of a sequence folder
as the tracking CLI reads it — ``velodyne/NNNNNN.bin`` and ``calib.txt`` (a KITTI tracking or
object calib file) or vista's ``calib.json``, and as known the labels (``label_02.txt``, or
a labelled raw drive's per-frame ``label_2/NNNNNNNNNN.txt``, linked into tracks by exact
type and size as ``sequence.link_object_labels`` does) and ``poses.txt`` — under any one
top folder of the archive.

Checked before anything is kept: the scans' names (digits, ``.bin``) and sizes (whole
16-byte points, at most ``MAX_SCAN_BYTES`` each), the calibration, the labels and the poses
parsed. Members are written under names of vista's choosing, never by the archive's paths
(``services.lib.archive``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath

import numpy as np

from contract.artifacts import Inspected
from services.lib import kitti
from services.lib.archive import (
    ArchiveError,
    Member,
    media_type,
    opened,
    read_in_order,
    read_member,
    write_tar_gz,
)
from services.lib.formats import checked

HINT = (
    "pack a sequence folder with `tar czf seq.tar.gz -C SEQ velodyne calib.txt label_02.txt "
    "poses.txt` (or calib.json, label_2/)"
)
MAX_SCAN_BYTES = 64 << 20
MAX_TEXT_BYTES = 256 << 20
SCAN = re.compile(r"^\d{1,10}\.bin$")
LABEL_FILE = re.compile(r"^\d{1,10}\.txt$")
TEXT_FILES = ("calib.txt", "calib.json", "label_02.txt", "poses.txt")
CALIBRATIONS = ("calib.txt", "calib.json")


@dataclass(frozen=True)
class LidarArchive:
    form: str
    scans: dict[str, str]
    """Member name → ``velodyne/NNNNNN.bin``."""
    texts: dict[str, str]
    """Member name → calib.txt or calib.json, label_02.txt or label_2/NNNN.txt, poses.txt."""
    frames: int
    labels: int
    """Label lines (0: none)."""
    tracks: int
    poses: bool
    media_type: str = "application/x-tar"


def _root(path: PurePosixPath) -> PurePosixPath:
    """The folder holding a member's ``velodyne/``."""
    return PurePosixPath(*path.parts[: path.parts.index("velodyne")])


def _plan(form: str, members: list[Member], archive: object) -> LidarArchive:
    roots = {
        _root(PurePosixPath(m.name))
        for m in members
        if "velodyne" in PurePosixPath(m.name).parts[:-1]
    }
    if not roots:
        raise ArchiveError("no velodyne/ folder of scans (NNNNNN.bin) in the archive")
    if len(roots) > 1:
        raise ArchiveError(
            f"velodyne/ appears under {len(roots)} folders: one sequence per archive"
        )
    root = roots.pop()
    scans, texts = {}, {}
    for member in members:
        path = PurePosixPath(member.name)
        if not path.is_relative_to(root):
            continue
        inside = path.relative_to(root)
        if inside.parts[:1] == ("velodyne",) and len(inside.parts) == 2 and inside.suffix == ".bin":
            if not SCAN.match(inside.name):
                raise ArchiveError(
                    f"{member.name}: a scan is named by its frame number (000042.bin)"
                )
            if member.size % kitti.POINT_BYTES or member.size > MAX_SCAN_BYTES:
                raise ArchiveError(
                    f"{member.name}: {member.size:,} bytes is not a scan (16-byte points, at most {MAX_SCAN_BYTES >> 20} MiB)"
                )
            scans[member.name] = f"velodyne/{int(inside.stem):06d}.bin"
        elif len(inside.parts) == 1 and inside.name in TEXT_FILES:
            texts[member.name] = inside.name
        elif inside.parts[:1] == ("label_2",) and len(inside.parts) == 2:
            if not LABEL_FILE.match(inside.name):
                raise ArchiveError(
                    f"{member.name}: a frame's labels are named by its number (0000000042.txt)"
                )
            texts[member.name] = f"label_2/{int(inside.stem):010d}.txt"
    if not scans:
        raise ArchiveError("velodyne/ holds no scans (NNNNNN.bin)")
    if len(set(scans.values())) != len(scans):
        raise ArchiveError("two scans have the same frame number")
    if not set(CALIBRATIONS) & set(texts.values()):
        raise ArchiveError(
            "no calib.txt (KITTI's calibration: P2, R_rect, Tr_velo_cam) nor calib.json "
            "(P_rect_02, R_rect_00, cam0_T_velo) beside velodyne/"
        )
    if "label_02.txt" in texts.values() and any(t.startswith("label_2/") for t in texts.values()):
        raise ArchiveError("both label_02.txt and label_2/: give the labels one way")
    parsed = {}
    for member, text in read_in_order(form, archive, members, dict.fromkeys(texts, MAX_TEXT_BYTES)):
        try:
            parsed[texts[member.name]] = text.decode()
        except UnicodeDecodeError:
            raise ArchiveError(f"{member.name} is not text") from None
    try:
        if "calib.txt" in parsed:
            kitti.parse_calibration(parsed["calib.txt"], "calib.txt")
        else:
            kitti.parse_calibration_json(parsed["calib.json"], "calib.json")
        labels = _labels(parsed)
        poses = (
            kitti.parse_poses(parsed["poses.txt"], "poses.txt") if "poses.txt" in parsed else None
        )
    except ValueError as exc:  # KittiError, and numpy's own on numbers it cannot shape
        raise ArchiveError(str(exc)) from None
    if poses is not None and len(poses) < len(scans):
        raise ArchiveError(f"poses.txt has {len(poses)} poses for {len(scans)} scans")
    return LidarArchive(
        form,
        scans,
        texts,
        frames=len(scans),
        labels=len(labels) if labels is not None else 0,
        tracks=len(np.unique(labels.track_id[labels.track_id >= 0])) if labels is not None else 0,
        poses=poses is not None,
    )


def _labels(parsed: dict[str, str]) -> kitti.Labels | None:
    """The sequence's labels: label_02.txt's, or label_2/'s frames linked into tracks."""
    from services.tracking.sequence import link_object_labels

    if "label_02.txt" in parsed:
        return kitti.parse_labels(parsed["label_02.txt"], "label_02.txt", tracking=True)
    frames = sorted(name for name in parsed if name.startswith("label_2/"))
    if not frames:
        return None
    return link_object_labels(
        [
            kitti.parse_labels(parsed[name], name, tracking=False).with_frame(
                int(PurePosixPath(name).stem)
            )
            for name in frames
        ]
    )


def inspect_lidar(path: Path) -> LidarArchive:
    """What the archive holds, checked without extracting it; ArchiveError naming the problem."""
    with opened(path, HINT) as (form, members, archive):
        plan = _plan(form, members, archive)
    return replace(plan, media_type=media_type(path, form))


def extract_lidar(path: Path, out_dir: Path) -> LidarArchive:
    """The archive written as a sequence folder at ``out_dir`` (read in the archive's order)."""
    with opened(path, HINT) as (form, members, archive):
        plan = _plan(form, members, archive)
        targets = {**plan.scans, **plan.texts}
        (out_dir / "velodyne").mkdir(parents=True, exist_ok=True)
        if any(t.startswith("label_2/") for t in plan.texts.values()):
            (out_dir / "label_2").mkdir(exist_ok=True)
        for member in members:
            target = targets.get(member.name)
            if target is not None:
                limit = MAX_SCAN_BYTES if target.endswith(".bin") else MAX_TEXT_BYTES
                (out_dir / target).write_bytes(read_member(form, archive, member, limit))
    return plan


def inspect_lidar_artifact(path: Path, declared: str) -> Inspected:
    """The ``lidar`` kind's check (``contract.artifacts.Inspect``): the archive planned as
    the tracking jobs read it."""
    found = checked(inspect_lidar, path, "a LiDAR sequence")
    kept = ("frames", "labels", "tracks", "poses")
    return Inspected(found.media_type, {name: getattr(found, name) for name in kept})


def write_lidar_archive(folder: Path, out: Path, *, labels: bool = True) -> Path:
    """A sequence folder's velodyne/, calib.txt, poses.txt (and label_02.txt) as the tar.gz
    a `lidar` artifact takes, under a top folder named like the sequence."""
    names = ["calib.txt", *(n for n in ("poses.txt",) if (folder / n).exists())]
    names += ["label_02.txt"] if labels and (folder / "label_02.txt").exists() else []
    scans = sorted((folder / "velodyne").glob("*.bin"))
    files = [(p, f"{folder.name}/velodyne/{p.name}") for p in scans]
    return write_tar_gz(out, files + [(folder / n, f"{folder.name}/{n}") for n in names])
