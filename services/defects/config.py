"""What a measurement is judged against (tolerances) and how it is taken (settings).

CONFIG.json — the inspection's tolerances, in the same shape as an inspection's
``tolerances`` in the API, and optional measurement settings:

    {"gap_mm": {"min": 0.5, "max": 3.0}, "step_mm": {"max": 0.5},
     "parallelism_mm": {"max": 0.5}, "mismatch_mm": {"max": 0.5},
     "surface": {"dent_depth_mm": 0.2, "scratch_depth_mm": 0.1, "color_delta_e": 3.0},
     "measurement": {"pitch_mm": 2.0, "cell_mm": 0.2, "edge_model": "auto",
                     "gap_mode": "walls"}}

Every key is optional: what is missing takes the default below.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

from services.defects.sections import EDGE_MODELS, GAP_MODES, SectionConfig
from services.defects.surface import SurfaceConfig


class ConfigError(ValueError):
    """A configuration that cannot be used, with the key at fault."""


@dataclass(frozen=True)
class Tolerances:
    gap_min_mm: float = 0.5
    gap_max_mm: float = 3.0
    step_max_mm: float = 0.5
    parallelism_max_mm: float = 0.5
    mismatch_max_mm: float = 0.5
    dent_depth_mm: float = 0.2
    """Also the limit for bumps (their height)."""
    scratch_depth_mm: float = 0.1
    color_delta_e: float = 3.0


@dataclass(frozen=True)
class MeasureConfig:
    tolerances: Tolerances = field(default_factory=Tolerances)
    cell_mm: float = 0.2
    """Height-map cell; raised to 1.5 × the point spacing for sparser clouds."""
    max_slope_deg: float = 30.0
    min_panel_area_mm2: float = 1000.0
    background_drop_mm: float = 8.0
    max_gap_mm: float = 10.0
    min_seam_length_mm: float = 20.0
    min_measured_share: float = 0.5
    """A seam with fewer measured sections than this share (or than three) yields no gap,
    parallelism or mismatch: it says it is unmeasured instead."""
    sections: SectionConfig = field(default_factory=SectionConfig)
    surface: SurfaceConfig | None = field(default_factory=SurfaceConfig)
    """None: seams and junctions only."""


_TOLERANCE_KEYS = {
    ("gap_mm", "min"): "gap_min_mm",
    ("gap_mm", "max"): "gap_max_mm",
    ("step_mm", "max"): "step_max_mm",
    ("parallelism_mm", "max"): "parallelism_max_mm",
    ("mismatch_mm", "max"): "mismatch_max_mm",
    ("surface", "dent_depth_mm"): "dent_depth_mm",
    ("surface", "scratch_depth_mm"): "scratch_depth_mm",
    ("surface", "color_delta_e"): "color_delta_e",
}
_MEASUREMENT_KEYS = {
    "cell_mm": ("", "cell_mm"),
    "max_gap_mm": ("", "max_gap_mm"),
    "min_seam_length_mm": ("", "min_seam_length_mm"),
    "min_panel_area_mm2": ("", "min_panel_area_mm2"),
    "pitch_mm": ("sections", "pitch_mm"),
    "slab_mm": ("sections", "slab_mm"),
    "edge_band_mm": ("sections", "edge_band_mm"),
    "top_band_mm": ("sections", "top_band_mm"),
    "max_view_deg": ("sections", "max_view_deg"),
}
_CHOICE_KEYS = {"edge_model": EDGE_MODELS, "gap_mode": GAP_MODES}
"""Settings that name a choice (``sections.py`` says what each means)."""


def _positive(value: Any, where: str, *, zero: bool = False) -> float:
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if not number or not (value > 0 or (zero and value == 0)) or value != value:
        kind = "a number ≥ 0" if zero else "a positive number"
        raise ConfigError(f"{where} must be {kind}, got {value!r}")
    return float(value)


def parse_config(document: Any, where: str = "config") -> MeasureConfig:
    """The MeasureConfig a CONFIG.json (or an inspection's tolerances) asks for."""
    if not isinstance(document, dict):
        raise ConfigError(f"{where}: expected a JSON object")
    known = {group for group, _ in _TOLERANCE_KEYS} | {"measurement"}
    unknown = sorted(set(document) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown}; known: {sorted(known)}")
    limits: dict[str, float] = {}
    for (group, key), name in _TOLERANCE_KEYS.items():
        section = document.get(group)
        if section is None:
            continue
        if not isinstance(section, dict):
            raise ConfigError(f"{where}.{group} must be an object")
        allowed = {k for g, k in _TOLERANCE_KEYS if g == group}
        if set(section) - allowed:
            raise ConfigError(
                f"{where}.{group}: unknown keys {sorted(set(section) - allowed)}; "
                f"known: {sorted(allowed)}"
            )
        if section.get(key) is not None:
            limits[name] = _positive(
                section[key], f"{where}.{group}.{key}", zero=name == "gap_min_mm"
            )
    tolerances = replace(Tolerances(), **limits)
    if tolerances.gap_min_mm >= tolerances.gap_max_mm:
        raise ConfigError(
            f"{where}.gap_mm: min {tolerances.gap_min_mm} must be below max {tolerances.gap_max_mm}"
        )
    config = MeasureConfig(tolerances=tolerances)
    settings = document.get("measurement") or {}
    if not isinstance(settings, dict):
        raise ConfigError(f"{where}.measurement must be an object")
    for key, value in settings.items():
        if key in _CHOICE_KEYS:
            if value not in _CHOICE_KEYS[key]:
                raise ConfigError(
                    f"{where}.measurement.{key} must be one of {list(_CHOICE_KEYS[key])}, "
                    f"got {value!r}"
                )
            config = replace(config, sections=replace(config.sections, **{key: value}))
            continue
        if key not in _MEASUREMENT_KEYS:
            known = sorted([*_MEASUREMENT_KEYS, *_CHOICE_KEYS])
            raise ConfigError(f"{where}.measurement: unknown key {key!r}; known: {known}")
        part, name = _MEASUREMENT_KEYS[key]
        number = _positive(value, f"{where}.measurement.{key}")
        if part:
            config = replace(config, **{part: replace(getattr(config, part), **{name: number})})
        else:
            config = replace(config, **{name: number})
    return config


def config_document(config: MeasureConfig) -> dict:
    """The CONFIG.json that gives ``config``'s tolerances and section settings."""
    t = config.tolerances
    return {
        "gap_mm": {"min": t.gap_min_mm, "max": t.gap_max_mm},
        "step_mm": {"max": t.step_max_mm},
        "parallelism_mm": {"max": t.parallelism_max_mm},
        "mismatch_mm": {"max": t.mismatch_max_mm},
        "surface": {
            "dent_depth_mm": t.dent_depth_mm,
            "scratch_depth_mm": t.scratch_depth_mm,
            "color_delta_e": t.color_delta_e,
        },
        "measurement": {
            "cell_mm": config.cell_mm,
            **{
                f.name: getattr(config.sections, f.name)
                for f in fields(config.sections)
                if f.name in _MEASUREMENT_KEYS or f.name in _CHOICE_KEYS
            },
        },
    }
