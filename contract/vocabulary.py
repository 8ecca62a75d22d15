"""The words both sides use: what a defect can be and how bad, which device a learned
service trains on, how long work reports its progress. The supervisor's tables and API,
the services' findings and CLIs read them from here."""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, get_args

DefectType = Literal[
    "gap", "step", "parallelism", "mismatch", "scratch", "dent", "bump", "color", "deviation"
]
Severity = Literal["info", "minor", "major", "critical"]
"""``info``: a measurement within tolerance (a seam), kept for review."""
DeviceChoice = Literal["auto", "cpu", "cuda"]
"""Where a network trains: ``auto`` takes CUDA when torch sees a GPU."""
DEFECT_TYPES: tuple[DefectType, ...] = get_args(DefectType)
SEVERITIES: tuple[Severity, ...] = get_args(Severity)
DEVICE_CHOICES: tuple[DeviceChoice, ...] = get_args(DeviceChoice)

ONNX_MEDIA_TYPE = "application/octet-stream"
"""How a model artifact is kept and served (ONNX has no registered media type)."""

Progress = Callable[[float, str], None]
"""Long work's report: the fraction done (0..1) and what it is doing."""
Say = Callable[[str], None]
"""A line of news for the user (a simulator's "drive 3/500")."""
Count = Callable[[int, int], None]
"""Items done of the total, after each one (a tracker's frames)."""
