"""A frame sequence in one file: a zip or tar archive (gzip, bzip2 or xz compressed or not) of
what ``vista odometry simulate`` writes — the PNG frames, ``camera.json`` and, when the
truth is known, ``truth.tum``.

The frames may sit in any one folder of the archive (``frames/``, ``seq/frames/`` or the
top); they are taken in name order, numbers by value (``2.png`` before ``10.png``); a
desktop's leftovers (``__MACOSX/``, ``._*``) are skipped. Nothing is extracted by the
archive's own paths: the members are read and written under names of vista's choosing, so a
member called ``../../etc/passwd`` cannot land outside the folder. What the archive expands
to is checked as it is read (``services.lib.archive``); camera.json, truth.tum and each frame
have limits of their own, and at upload every frame is decoded once (a frame OpenCV cannot
read, or of another size than camera.json says, is refused naming it).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath

from contract.artifacts import Inspected
from services.lib.archive import ArchiveError as SequenceError
from services.lib.archive import (
    JsonTooDeep,
    Member,
    decode_image,
    media_type,
    opened,
    parse_json,
    read_in_order,
    read_member,
    write_tar_gz,
)
from services.lib.formats import checked
from services.odometry.camera import FloorCamera
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
    camera: FloorCamera
    camera_member: str
    truth_member: str | None
    """``None``: the archive has no truth."""
    media_type: str = "application/x-tar"
    """``application/zip``, a compressed tar's compression or ``application/x-tar``."""


def _frame_order(name: str) -> list:
    """Numbers by value: 2.png before 10.png (compared as digit strings by length, so a
    name of thousands of digits sorts too)."""
    parts = re.split(r"(\d+)", name)
    return [(len(p.lstrip("0")), p.lstrip("0")) if k % 2 else p for k, p in enumerate(parts)]


def _one(members: list[Member], file_name: str, *, required: bool) -> Member | None:
    found = [m for m in members if PurePosixPath(m.name).name == file_name]
    if len(found) > 1:
        names = ", ".join(m.name for m in found[:3])
        raise SequenceError(f"{len(found)} files called {file_name} ({names}): one")
    if not found and required:
        raise SequenceError(f"no {file_name} in the archive (the camera's size, fps and mm/px)")
    return found[0] if found else None


def _camera(member: Member, data: bytes) -> FloorCamera:
    try:
        document = parse_json(data)
    except JsonTooDeep as exc:
        raise SequenceError(f"{member.name} {exc}") from None
    except ValueError as exc:
        raise SequenceError(f"{member.name} is not JSON ({exc})") from None
    try:
        return FloorCamera.from_document(document)
    except (ValueError, OverflowError) as exc:  # int() of an infinite size overflows
        detail = str(exc).removeprefix("camera.json: ")
        raise SequenceError(f"{member.name}: {detail}") from None


def _truth(member: Member, data: bytes, frames: int) -> None:
    try:
        truth = parse_tum(data.decode(), member.name)
    except (UnicodeDecodeError, ValueError) as exc:
        raise SequenceError(f"{member.name}: not a TUM trajectory ({exc})") from None
    if len(truth) != frames:
        raise SequenceError(f"{member.name} has {len(truth)} poses for {frames} frames")


def _read_once(
    form: str, archive: object, members: list[Member], limits: dict[str, int]
) -> tuple[dict[str, bytes], dict[str, tuple[int, int]]]:
    """camera.json's and truth.tum's bytes, and each frame decoded once, kept as its
    (height, width): one pass in the archive's order."""
    texts, shapes = {}, {}
    for member, data in read_in_order(form, archive, members, limits):
        if member.name.lower().endswith(".png"):
            shapes[member.name] = decode_image(member.name, data).shape[:2]
        else:
            texts[member.name] = data
    return texts, shapes


def _inspect(
    form: str, members: list[Member], archive: object, *, decode_frames: bool
) -> SequenceArchive:
    pngs = sorted({m.name for m in members if m.name.lower().endswith(".png")}, key=_frame_order)
    folders = sorted({str(PurePosixPath(name).parent) for name in pngs})
    if len(folders) > 1:
        shown = ", ".join(folders[:3])
        raise SequenceError(f"the PNG frames must be in one folder, not {len(folders)} ({shown})")
    if len(pngs) < 2:
        raise SequenceError(f"needs at least 2 PNG frames, found {len(pngs)}")
    camera_member = _one(members, "camera.json", required=True)
    truth_member = _one(members, "truth.tum", required=False)
    limits = {camera_member.name: MAX_MEMBER_BYTES["camera.json"]}
    if truth_member is not None:
        limits[truth_member.name] = MAX_MEMBER_BYTES["truth.tum"]
    if decode_frames:
        limits |= {name: MAX_MEMBER_BYTES["frame"] for name in pngs}
    texts, shapes = _read_once(form, archive, members, limits)
    camera = _camera(camera_member, texts[camera_member.name])
    if truth_member is not None:
        _truth(truth_member, texts[truth_member.name], len(pngs))
    size = (camera.height, camera.width)
    wrong = [name for name in pngs if shapes.get(name, size) != size]
    if wrong:
        height, width = shapes[wrong[0]]
        raise SequenceError(
            f"{wrong[0]} is {width} × {height} pixels, but camera.json says "
            f"{camera.width} × {camera.height}"
        )
    return SequenceArchive(
        form, tuple(pngs), camera, camera_member.name, truth_member.name if truth_member else None
    )


def inspect_sequence(path: Path) -> SequenceArchive:
    """The archive's frames (each decoded once), camera and truth, checked; SequenceError
    naming the problem."""
    with opened(path, HINT) as (form, members, archive):
        found = _inspect(form, members, archive, decode_frames=True)
    return replace(found, media_type=media_type(path, form))


def extract_sequence(path: Path, out_dir: Path) -> SequenceArchive:
    """The archive written as a sequence folder: ``out_dir/frames/NNNNNN.png`` (in the
    frames' name order), ``camera.json`` and ``truth.tum`` when the archive has one.

    The members are read in the archive's own order (a compressed tar is one stream: read
    out of order, every frame would decompress it again from the start)."""
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    with opened(path, HINT) as (form, members, archive):
        found = _inspect(form, members, archive, decode_frames=False)
        targets = {name: frames_dir / f"{k:06d}.png" for k, name in enumerate(found.frames)}
        targets[found.camera_member] = out_dir / "camera.json"
        if found.truth_member is not None:
            targets[found.truth_member] = out_dir / "truth.tum"
        for member in members:
            if member.name in targets:
                limit = MAX_MEMBER_BYTES.get(targets[member.name].name, MAX_MEMBER_BYTES["frame"])
                targets[member.name].write_bytes(read_member(form, archive, member, limit))
    return found


def inspect_frames(path: Path, declared: str) -> Inspected:
    """The ``frames`` kind's check (``contract.artifacts.Inspect``): the archive as a run
    reads it, its frames counted and its camera read."""
    found = checked(inspect_sequence, path, "a frame sequence")
    meta = {
        "frames": len(found.frames),
        "camera": found.camera.document(),
        "truth": found.truth_member is not None,
    }
    return Inspected(found.media_type, meta)


def write_sequence_archive(folder: Path, out: Path, *, truth: bool = True) -> Path:
    """A simulated sequence's frames/, camera.json (and truth.tum) as the tar.gz a `frames`
    artifact takes, under a top folder named like the sequence."""
    names = ["camera.json", *(["truth.tum"] if truth else [])]
    files = [*sorted((folder / "frames").glob("*.png")), *(folder / n for n in names)]
    return write_tar_gz(out, [(p, f"{folder.name}/{p.relative_to(folder)}") for p in files])
