"""Planar trajectories in the TUM format: ``t tx ty tz qx qy qz qw`` per line, seconds and
metres, read by standard tools (evo).

A pose is the camera's in the frame of the first camera (x along the image columns, y along
the rows, z into the floor); vista's planar poses are (x_mm, y_mm, θ_rad) with θ about z,
and the height change (toward the floor positive) as tz.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.artifacts import ArtifactRefused, Inspected
from services.lib.formats import limit_size


@dataclass(frozen=True)
class Trajectory2D:
    t_s: np.ndarray
    """(N,) seconds."""
    pose: np.ndarray
    """(N, 3): x_mm, y_mm, θ_rad of each camera in the first camera's frame."""
    z_mm: np.ndarray | None = None
    """(N,) the camera's move toward the floor (mm), where known."""

    def __len__(self) -> int:
        return len(self.t_s)


def write_tum(path: Path, trajectory: Trajectory2D) -> None:
    theta = trajectory.pose[:, 2]
    z_mm = trajectory.z_mm if trajectory.z_mm is not None else np.zeros(len(theta))
    rows = np.column_stack(
        [
            trajectory.t_s,
            trajectory.pose[:, 0] / 1000,
            trajectory.pose[:, 1] / 1000,
            z_mm / 1000,
            np.zeros(len(theta)),
            np.zeros(len(theta)),
            np.sin(theta / 2),
            np.cos(theta / 2),
        ]
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, rows, fmt=["%.6f"] + ["%.9f"] * 7)


def read_tum(path: Path) -> Trajectory2D:
    """A TUM file as a planar trajectory; ValueError naming the line that is not a pose,
    or a rotation that leaves the floor's plane."""
    return parse_tum(path.read_text(), str(path))


def parse_tum(text: str, path: str) -> Trajectory2D:
    """``read_tum`` of a file's ``text`` (``path`` names it in the errors)."""
    lines = text.splitlines()
    rows = []
    for number, line in enumerate(lines, 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        try:
            values = [float(v) for v in text.split()]
        except ValueError:
            raise ValueError(f"{path}:{number}: not numbers: {text[:60]!r}") from None
        if len(values) != 8 or not np.isfinite(values).all():
            raise ValueError(f"{path}:{number}: a pose is 8 finite numbers: t tx ty tz qx qy qz qw")
        rows.append(values)
    if not rows:
        raise ValueError(f"{path}: no poses")
    data = np.array(rows)
    if np.any(np.diff(data[:, 0]) <= 0):
        line = int(np.argmax(np.diff(data[:, 0]) <= 0)) + 2
        raise ValueError(f"{path}: the times must increase (pose {line})")
    norm = np.linalg.norm(data[:, 4:8], axis=1, keepdims=True)
    if np.any(norm < 1e-9):  # no rotation; dividing by it would make the pose NaN
        raise ValueError(f"{path}: pose {int(np.argmax(norm < 1e-9)) + 1} has a zero quaternion")
    q = data[:, 4:8] / norm
    tilt = np.hypot(q[:, 0], q[:, 1])
    if np.any(tilt > 1e-3):
        raise ValueError(
            f"{path}: pose {int(np.argmax(tilt > 1e-3)) + 1} rotates out of the floor's plane"
        )
    theta = 2 * np.arctan2(q[:, 2], q[:, 3])
    theta = np.angle(np.exp(1j * theta))
    pose = np.column_stack([data[:, 1] * 1000, data[:, 2] * 1000, theta])
    return Trajectory2D(data[:, 0], pose, data[:, 3] * 1000)


MAX_TUM_BYTES = 256 * 1024 * 1024


def inspect_trajectory(path: Path, declared: str) -> Inspected:
    """The ``trajectory`` kind's check (``contract.artifacts.Inspect``): parsed as a run's
    evaluation reads it."""
    limit_size(path, MAX_TUM_BYTES, "TUM trajectories")
    try:
        parse_tum(path.read_text(encoding="utf-8"), path.name)
    except ValueError as exc:  # UnicodeDecodeError too
        raise ArtifactRefused(f"is not a TUM trajectory: {exc}") from exc
    return Inspected("text/plain")
