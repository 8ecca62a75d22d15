"""The stitching file contract: PAIRS.json in, HANDEYE.json out (4×4 row-major, mm).

PAIRS.json  ``{"pairs": [{"base_T_flange": M, "sensor_T_target": M}, …]}``
HANDEYE.json ``{"flange_T_sensor": M, "base_T_target": M, "method": …, "residual_mm": …, …,
"noise": {"robot_sigma_mm": …, …}}`` (the noise the calibration was given)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from services.lib.archive import read_json
from services.lib.pointcloud.transforms import TransformError, check_rigid, to_json
from services.stitching.calibration import HandEye
from services.stitching.kinds import NoiseModel


class StitchingFileError(ValueError):
    """A PAIRS/SCANS/HANDEYE file vista cannot use; the message names the file and place."""


def load_json(path: Path) -> Any:
    try:
        return read_json(path)
    except ValueError as exc:
        raise StitchingFileError(str(exc)) from None


def _matrix(value: Any, where: str) -> np.ndarray:
    try:
        return check_rigid(value, where)
    except TransformError as exc:
        raise StitchingFileError(str(exc)) from None


def read_pairs(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(base_T_flange, sensor_T_target) as (k, 4, 4) arrays."""
    data = load_json(path)
    pairs = data.get("pairs") if isinstance(data, dict) else None
    if not isinstance(pairs, list) or not pairs:
        raise StitchingFileError(f'{path}: expected {{"pairs": [...]}} with at least one pair')
    flange, target = [], []
    for i, pair in enumerate(pairs):
        if not isinstance(pair, dict):
            raise StitchingFileError(f"{path}: pairs[{i}] must be an object")
        for key in ("base_T_flange", "sensor_T_target"):
            if key not in pair:
                raise StitchingFileError(f"{path}: pairs[{i}] has no {key}")
        flange.append(_matrix(pair["base_T_flange"], f"{path}: pairs[{i}].base_T_flange"))
        target.append(_matrix(pair["sensor_T_target"], f"{path}: pairs[{i}].sensor_T_target"))
    return np.stack(flange), np.stack(target)


def write_pairs(path: Path, base_T_flange: np.ndarray, sensor_T_target: np.ndarray) -> None:
    pairs = [
        {"base_T_flange": to_json(f), "sensor_T_target": to_json(s)}
        for f, s in zip(base_T_flange, sensor_T_target, strict=True)
    ]
    Path(path).write_text(json.dumps({"pairs": pairs}, indent=1) + "\n")


def parse_scans(data: Any, where: str) -> tuple[list[str], np.ndarray]:
    """The SCANS.json document: scan file names as written and their (n, 4, 4) base_T_flange."""
    scans = data.get("scans") if isinstance(data, dict) else None
    if not isinstance(scans, list) or not scans:
        raise StitchingFileError(f'{where}: expected {{"scans": [...]}} with at least one scan')
    names, poses = [], []
    for i, scan in enumerate(scans):
        if not isinstance(scan, dict) or not isinstance(scan.get("file"), str):
            raise StitchingFileError(f"{where}: scans[{i}] needs a file name")
        if "base_T_flange" not in scan:
            raise StitchingFileError(f"{where}: scans[{i}] has no base_T_flange")
        names.append(scan["file"])
        poses.append(_matrix(scan["base_T_flange"], f"{where}: scans[{i}].base_T_flange"))
    return names, np.stack(poses)


def read_scans(path: Path) -> tuple[list[Path], np.ndarray]:
    """SCANS.json: the scan files (relative to SCANS.json) and their (n, 4, 4) base_T_flange."""
    names, poses = parse_scans(load_json(path), str(path))
    files = [Path(path).parent / name for name in names]
    for i, file in enumerate(files):
        if not file.is_file():
            raise StitchingFileError(f"{path}: scans[{i}].file {names[i]!r} does not exist")
    return files, poses


def write_scans(path: Path, files: list[str], base_T_flange: np.ndarray) -> None:
    scans = [
        {"file": f, "base_T_flange": to_json(m)} for f, m in zip(files, base_T_flange, strict=True)
    ]
    Path(path).write_text(json.dumps({"scans": scans}, indent=1) + "\n")


def handeye_json(result: HandEye) -> dict:
    return {
        "flange_T_sensor": to_json(result.flange_T_sensor),
        "base_T_target": to_json(result.base_T_target),
        "method": result.method,
        "residual_mm": result.residual_mm,
        "pair_residuals_mm": list(result.pair_residuals_mm),
        "used_pairs": list(result.used_pairs),
        "dropped_pairs": [
            {"index": d.index, "chi2": d.chi2, "residual_mm": d.residual_mm} for d in result.dropped
        ],
        "sigma_translation_mm": result.sigma_translation_mm,
        "sigma_rotation_deg": result.sigma_rotation_deg,
        "seconds": result.seconds,
        "details": result.details,
        "noise": None if result.noise is None else _noise_json(result.noise),
    }


def _noise_json(noise: NoiseModel) -> dict:
    """The noise's own fields (a calibrate job's parameters are a noise model, and more)."""
    return {name: getattr(noise, name) for name in NoiseModel.model_fields}


def write_handeye(path: Path, result: HandEye) -> None:
    Path(path).write_text(json.dumps(handeye_json(result), indent=1) + "\n")


def read_handeye(path: Path) -> tuple[np.ndarray, dict]:
    """flange_T_sensor and the whole document (for its uncertainty, noise and method)."""
    data = load_json(path)
    if not isinstance(data, dict) or "flange_T_sensor" not in data:
        raise StitchingFileError(f"{path}: expected an object with flange_T_sensor")
    try:
        NoiseModel.model_validate(data.get("noise") or {})
    except ValidationError as exc:
        first = exc.errors()[0]
        at = ".".join(["noise", *(str(p) for p in first["loc"])])
        raise StitchingFileError(f"{path}: {at}: {first['msg']}") from None
    return _matrix(data["flange_T_sensor"], f"{path}: flange_T_sensor"), data


@dataclass(frozen=True)
class SimulatedTruth:
    """truth.json of ``vista stitching simulate``: what the simulated measurements hide."""

    component: str
    base_T_part: np.ndarray
    flange_T_sensor: np.ndarray
    scan_base_T_flange: np.ndarray
    """(n, 4, 4) true robot poses of the scans."""
    model_bounds_mm: tuple[np.ndarray, np.ndarray]


def read_truth(path: Path) -> SimulatedTruth:
    data = load_json(path)
    keys = ("component", "base_T_part", "flange_T_sensor", "scan_true_base_T_flange")
    keys += ("model_bounds_min_mm", "model_bounds_max_mm")
    missing = [k for k in keys if not isinstance(data, dict) or k not in data]
    if missing:
        raise StitchingFileError(f"{path}: not a truth.json of vista simulate; no {missing}")
    return SimulatedTruth(
        component=str(data["component"]),
        base_T_part=_matrix(data["base_T_part"], f"{path}: base_T_part"),
        flange_T_sensor=_matrix(data["flange_T_sensor"], f"{path}: flange_T_sensor"),
        scan_base_T_flange=np.stack(
            [
                _matrix(m, f"{path}: scan_true_base_T_flange[{i}]")
                for i, m in enumerate(data["scan_true_base_T_flange"])
            ]
        ),
        model_bounds_mm=(
            np.asarray(data["model_bounds_min_mm"], float),
            np.asarray(data["model_bounds_max_mm"], float),
        ),
    )
