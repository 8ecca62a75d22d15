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

from dataclasses import dataclass, field
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from contract.tolerances import Limits, Tolerances, limits_of, tolerances_of
from contract.training import config_from
from services.defects.kinds import MeasureSettings
from services.defects.sections import SETTINGS, SectionConfig
from services.defects.surface import SurfaceConfig

Model = TypeVar("Model", bound=BaseModel)


class ConfigError(ValueError):
    """A configuration that cannot be used, with the key at fault."""


@dataclass(frozen=True)
class MeasureConfig:
    tolerances: Limits = field(default_factory=Limits)
    cell_mm: float = SETTINGS["cell_mm"].default
    """Height-map cell; raised to 1.5 × the point spacing for sparser clouds."""
    max_slope_deg: float = 30.0
    min_panel_area_mm2: float = SETTINGS["min_panel_area_mm2"].default
    background_drop_mm: float = 8.0
    max_gap_mm: float = SETTINGS["max_gap_mm"].default
    min_seam_length_mm: float = SETTINGS["min_seam_length_mm"].default
    min_measured_share: float = 0.5
    """A seam with fewer measured sections than this share (or than three) yields no gap,
    parallelism or mismatch: it says it is unmeasured instead."""
    sections: SectionConfig = field(default_factory=SectionConfig)
    surface: SurfaceConfig | None = field(default_factory=SurfaceConfig)
    """None: seams and junctions only."""


def parse_config(document: Any, where: str = "config") -> MeasureConfig:
    """The MeasureConfig a CONFIG.json (or an inspection's tolerances) asks for."""
    if not isinstance(document, dict):
        raise ConfigError(f"{where}: expected a JSON object")
    limits = {k: v for k, v in document.items() if k != "measurement"}
    tolerances = _validated(Tolerances, limits, where)
    settings = _validated(
        MeasureSettings, document.get("measurement") or {}, f"{where}.measurement"
    )
    return measure_config(limits_of(tolerances), settings)


def _validated(model: type[Model], document: Any, where: str) -> Model:
    """``document`` as ``model``; its first refusal a ConfigError naming the key."""
    try:
        return model.model_validate(document)
    except ValidationError as exc:
        first = exc.errors()[0]
        at = ".".join([where, *(str(p) for p in first["loc"])])
        raise ConfigError(f"{at}: {first['msg']}") from exc


def measure_config(tolerances: Limits, settings: MeasureSettings) -> MeasureConfig:
    """The measurement ``settings`` ask for (a job's params or CONFIG.json's), judged
    against ``tolerances``."""
    sections = config_from(SectionConfig, settings)
    return config_from(MeasureConfig, settings, tolerances=tolerances, sections=sections)


def config_document(config: MeasureConfig) -> dict:
    """The CONFIG.json that gives ``config``'s tolerances and measurement settings."""
    return {
        **tolerances_of(config.tolerances).model_dump(exclude_none=True),
        "measurement": {
            name: getattr(config.sections if hasattr(config.sections, name) else config, name)
            for name in SETTINGS
        },
    }
