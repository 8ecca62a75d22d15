"""Small floor-camera sequences for the tests, packed as the `frames` artifact takes them."""

from __future__ import annotations

import io
import tarfile
import zipfile
from pathlib import Path

from services.odometry.camera import FloorCamera
from services.odometry.simulate import simulate_sequence

SMALL_CAMERA = FloorCamera(width=200, height=150, fps=60.0, mm_per_px=0.6)


def small_sequence(out: Path, *, seconds: float = 0.3, seed: int = 5) -> Path:
    """A lawnmower start over asphalt seen by a 200 × 150 camera (0.6 mm/px)."""
    simulate_sequence(
        out, floor="asphalt", path="lawnmower", seconds=seconds, seed=seed, camera=SMALL_CAMERA
    )
    return out


def pack(folder: Path, archive: Path, *, truth: bool = True) -> Path:
    """``folder``'s frames/, camera.json (and truth.tum) as a zip or a tar(.gz) by the
    archive's suffix, in a top folder of the sequence's name as `tar -C parent` makes it."""
    names = ["camera.json", *(["truth.tum"] if truth else [])]
    files = [*sorted((folder / "frames").glob("*.png"))[::-1], *(folder / n for n in names)]
    if archive.suffix == ".zip":
        with zipfile.ZipFile(archive, "w") as out:
            for path in files:
                out.write(path, f"{folder.name}/{path.relative_to(folder)}")
    else:
        with tarfile.open(archive, "w:gz" if archive.suffix == ".gz" else "w") as out:
            for path in files:
                out.add(path, f"{folder.name}/{path.relative_to(folder)}")
    return archive


def archive_bytes(members: dict[str, bytes], form: str) -> bytes:
    """``members`` (name → bytes, in that order) packed as ``zip`` or ``tar``, ``tar.gz``,
    ``tar.bz2``, ``tar.xz``, in memory."""
    out = io.BytesIO()
    if form == "zip":
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
            for name, data in members.items():
                archive.writestr(name, data)
        return out.getvalue()
    mode = "w" if form == "tar" else f"w:{form.removeprefix('tar.')}"
    with tarfile.open(fileobj=out, mode=mode) as archive:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            archive.addfile(info, io.BytesIO(data))
    return out.getvalue()


def sequence_members(folder: Path) -> dict[str, bytes]:
    """A simulated sequence folder's files as archive members under ``seq/``."""
    files = [
        *sorted((folder / "frames").glob("*.png")),
        folder / "camera.json",
        folder / "truth.tum",
    ]
    return {f"seq/{path.relative_to(folder)}": path.read_bytes() for path in files}
