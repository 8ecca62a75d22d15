"""What a measurement is judged against (tolerances) and how it is taken (settings).

CONFIG.json — the inspection's tolerances, in the same shape as an inspection's
``tolerances`` in the API (``contract.tolerances.Tolerances``), and optional measurement
settings (``services.defects.kinds.MeasureSettings``, the job's parameters):

    {"gap_mm": {"min": …, "max": …}, "step_mm": {"max": …}, "parallelism_mm": {"max": …},
     "mismatch_mm": {"max": …},
     "surface": {"dent_depth_mm": …, "scratch_depth_mm": …, "color_delta_e": …},
     "measurement": {"pitch_mm": …, "cell_mm": …, "edge_model": …, "gap_mode": …, …}}

Every key is optional: what is missing takes its default, declared once in those models
(``contract.tolerances.Limits`` for the limits).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from contract.tolerances import Limits, Tolerances, limits_of, tolerances_of
from contract.training import config_from
from services.defects.kinds import MeasureSettings
from services.defects.sections import SETTINGS, SectionConfig
from services.defects.surface import SurfaceConfig
from services.lib.archive import read_json

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
    tolerances, settings = config_parts(document, where)
    return measure_config(limits_of(tolerances), settings)


def config_parts(document: Any, where: str = "config") -> tuple[Tolerances, MeasureSettings]:
    """A CONFIG.json's tolerances and measurement settings; ConfigError naming the key."""
    if not isinstance(document, dict):
        raise ConfigError(f"{where}: expected a JSON object")
    limits = {k: v for k, v in document.items() if k != "measurement"}
    tolerances = _validated(Tolerances, limits, where)
    settings = _validated(
        MeasureSettings, document.get("measurement") or {}, f"{where}.measurement"
    )
    return tolerances, settings


def read_config(
    path: Path | None, options: MeasureSettings, given: set[str]
) -> tuple[Tolerances, MeasureSettings]:
    """The tolerances and settings a command measures with: CONFIG.json's at ``path``
    (every default without one), its `measurement` block overridden by the ``options``
    named in ``given`` (those typed on the command line). ValueError naming the file."""
    if path is None:
        return Tolerances(), options
    tolerances, settings = config_parts(read_json(path), str(path))
    return tolerances, settings.model_copy(update={n: getattr(options, n) for n in given})


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
