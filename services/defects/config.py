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

from pydantic import ValidationError

from contract.tolerances import Limits, Tolerances, limits_of, tolerances_of
from services.defects.sections import EDGE_MODELS, GAP_MODES, SectionConfig
from services.defects.surface import SurfaceConfig


class ConfigError(ValueError):
    """A configuration that cannot be used, with the key at fault."""


@dataclass(frozen=True)
class MeasureConfig:
    tolerances: Limits = field(default_factory=Limits)
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


def _positive(value: Any, where: str) -> float:
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if not number or not value > 0 or value != value:
        raise ConfigError(f"{where} must be a positive number, got {value!r}")
    return float(value)


def parse_config(document: Any, where: str = "config") -> MeasureConfig:
    """The MeasureConfig a CONFIG.json (or an inspection's tolerances) asks for."""
    if not isinstance(document, dict):
        raise ConfigError(f"{where}: expected a JSON object")
    try:
        document_tolerances = Tolerances.model_validate(
            {k: v for k, v in document.items() if k != "measurement"}
        )
    except ValidationError as exc:
        first = exc.errors()[0]
        at = ".".join([where, *(str(p) for p in first["loc"])])
        raise ConfigError(f"{at}: {first['msg']}") from exc
    config = MeasureConfig(tolerances=limits_of(document_tolerances))
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
    return {
        **tolerances_of(config.tolerances).model_dump(exclude_none=True),
        "measurement": {
            "cell_mm": config.cell_mm,
            **{
                f.name: getattr(config.sections, f.name)
                for f in fields(config.sections)
                if f.name in _MEASUREMENT_KEYS or f.name in _CHOICE_KEYS
            },
        },
    }
