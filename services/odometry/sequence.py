"""A frame sequence in one file: a zip or tar archive (gzip, bzip2 or xz compressed or not) of
what ``vista odometry simulate`` writes — the PNG frames, ``camera.json`` and, when the
truth is known, ``truth.tum``.

The frames may sit in any one folder of the archive (``frames/``, ``seq/frames/`` or the
top); they are taken in name order, numbers by value (``2.png`` before ``10.png``); a
desktop's leftovers (``__MACOSX/``, ``._*``) are skipped. Nothing is extracted by the
archive's own paths: the members are read and written under names of vista's choosing, so a
member called ``../../etc/passwd`` cannot land outside the folder. Sizes are checked before
anything is read: a tar's listing stops once its files pass ``services.archive.MAX_ARCHIVE_BYTES``, and
camera.json, truth.tum and each frame have limits of their own.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath

from services.archive import ArchiveError as SequenceError
from services.archive import Member, check_total, media_type, opened, read_member
from services.odometry.camera import Camera
from services.odometry.tum import parse_tum

MAX_MEMBER_BYTES = {"camera.json": 1 << 20, "truth.tum": 256 << 20, "frame": 256 << 20}
HINT = "pack a sequence folder with `tar czf seq.tar.gz -C SEQ frames camera.json truth.tum`"


@dataclass(frozen=True)
class SequenceArchive:
    """What a sequence archive holds, checked without extracting it."""

    form: str
    """``zip`` or ``tar``."""
    frames: tuple[str, ...]
    """The frames' member names in order."""
    camera: Camera
    camera_member: str
    truth_member: str | None
    """``None``: the archive has no truth."""
    media_type: str = "application/x-tar"
    """``application/zip``, a compressed tar's compression or ``application/x-tar``."""


def _frame_order(name: str) -> list:
    """Numbers by value: 2.png before 10.png."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def _one(members: list[Member], file_name: str, *, required: bool) -> Member | None:
    found = [m for m in members if PurePosixPath(m.name).name == file_name]
    if len(found) > 1:
        names = ", ".join(m.name for m in found[:3])
        raise SequenceError(f"{len(found)} files called {file_name} ({names}): one")
    if not found and required:
        raise SequenceError(f"no {file_name} in the archive (the camera's size, fps and mm/px)")
    return found[0] if found else None


def _inspect(form: str, members: list[Member], archive: object) -> SequenceArchive:
    check_total(members)
    pngs = sorted({m.name for m in members if m.name.lower().endswith(".png")}, key=_frame_order)
    folders = sorted({str(PurePosixPath(name).parent) for name in pngs})
    if len(folders) > 1:
        shown = ", ".join(folders[:3])
        raise SequenceError(f"the PNG frames must be in one folder, not {len(folders)} ({shown})")
    if len(pngs) < 2:
        raise SequenceError(f"needs at least 2 PNG frames, found {len(pngs)}")
    camera_member = _one(members, "camera.json", required=True)
    try:
        text = read_member(form, archive, camera_member, MAX_MEMBER_BYTES["camera.json"])
        camera = Camera.from_document(json.loads(text))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{camera_member.name} is not JSON ({exc})") from None
    except ValueError as exc:
        detail = str(exc).removeprefix("camera.json: ")
        raise SequenceError(f"{camera_member.name}: {detail}") from None
    truth_member = _one(members, "truth.tum", required=False)
    if truth_member is not None:
        try:
            text = read_member(form, archive, truth_member, MAX_MEMBER_BYTES["truth.tum"])
            truth = parse_tum(text.decode(), truth_member.name)
        except (UnicodeDecodeError, ValueError) as exc:
            raise SequenceError(f"{truth_member.name}: not a TUM trajectory ({exc})") from None
        if len(truth) != len(pngs):
            raise SequenceError(
                f"{truth_member.name} has {len(truth)} poses for {len(pngs)} frames"
            )
    return SequenceArchive(
        form, tuple(pngs), camera, camera_member.name, truth_member.name if truth_member else None
    )


def inspect_sequence(path: Path) -> SequenceArchive:
    """The archive's frames, camera and truth, checked; SequenceError naming the problem."""
    with opened(path, HINT) as (form, members, archive):
        found = _inspect(form, members, archive)
    return replace(found, media_type=media_type(path, form))


def extract_sequence(path: Path, out_dir: Path) -> SequenceArchive:
    """The archive written as a sequence folder: ``out_dir/frames/NNNNNN.png`` (in the
    frames' name order), ``camera.json`` and ``truth.tum`` when the archive has one.

    The members are read in the archive's own order (a compressed tar is one stream: read
    out of order, every frame would decompress it again from the start)."""
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    with opened(path, HINT) as (form, members, archive):
        found = _inspect(form, members, archive)
        targets = {name: frames_dir / f"{k:06d}.png" for k, name in enumerate(found.frames)}
        targets[found.camera_member] = out_dir / "camera.json"
        if found.truth_member is not None:
            targets[found.truth_member] = out_dir / "truth.tum"
        for member in members:
            if member.name in targets:
                limit = MAX_MEMBER_BYTES.get(targets[member.name].name, MAX_MEMBER_BYTES["frame"])
                targets[member.name].write_bytes(read_member(form, archive, member, limit))
    return found
