"""What a job's run page shows of its results: a few typed panels that a service builds from
its own outputs (its kind's ``view`` hook, named by import path as the handler is) and that
every client draws alike. The supervisor knows no file's layout: it calls the hook on the
job's stored outputs and serves the panels (``GET /jobs/{id}/view``); a new service gets its
run page by declaring a hook, without editing the dashboard.

Units are in the labels: a panel carries numbers and says what they are.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field


@dataclass(frozen=True)
class Figure:
    label: str
    value: float | int | str | None
    """None: unmeasured (``note`` says why)."""
    unit: str = ""
    note: str = ""


@dataclass(frozen=True)
class Figures:
    """A run's headline numbers, as a two-column table."""

    title: str
    figures: list[Figure]
    type: Literal["figures"] = "figures"


@dataclass(frozen=True)
class Line:
    name: str
    x: list[float]
    y: list[float]
    band: list[float] | None = None
    """± this much around each point, in the axes' unit (a 1σ band; on ``equal_axes`` plots a
    circle of this radius, the position's uncertainty)."""
    style: Literal["line", "points"] = "line"
    """``points``: marks (flagged pairs, resets) rather than a curve."""
    colour: str | None = None
    """``#rrggbb`` when the colour means something (a verdict drawn so elsewhere too);
    None: the client's next."""


@dataclass(frozen=True)
class Plot:
    """Curves and marks over two axes (a path in the floor plane, a loss per epoch, an
    error against distance)."""

    title: str
    x_label: str
    y_label: str
    lines: list[Line]
    equal_axes: bool = False
    """A path: one unit is as long on both axes (a straight path stays straight)."""
    log_y: bool = False
    type: Literal["plot"] = "plot"


@dataclass(frozen=True)
class ColourScale:
    """What a layer's colours mean: a bar from ``low`` to ``high`` through ``colours``."""

    colours: list[str]
    """CSS colours, low to high."""
    low: str
    high: str


@dataclass(frozen=True)
class Picture:
    label: str
    layers: list[str]
    """Files (outputs by name, inputs by ``kind/name``) drawn in place of one another, a
    slider between them: an image, its depth map, its error map."""
    layer_names: list[str]
    artifact_ids: list[int] = field(default_factory=list)
    """Filled by the supervisor: the stored artifact of each layer (0: not stored)."""
    layer_scales: list[ColourScale | None] = field(default_factory=list)
    """Each layer's colour bar (None, or missing: a layer without one, such as a photo)."""


@dataclass(frozen=True)
class Pictures:
    title: str
    pictures: list[Picture]
    type: Literal["pictures"] = "pictures"


@dataclass(frozen=True)
class Table:
    """Rows of values under named columns (a measurement's seams), with a note below."""

    title: str
    columns: list[str]
    rows: list[list[str | float | int | None]]
    note: str = ""
    type: Literal["table"] = "table"


@dataclass(frozen=True)
class CrossSections:
    """Cross-sections along seams, for a page to step through: per seam (``seam``,
    ``panels``, ``length_mm``) its ``sections``, each at ``along_mm`` with what was measured
    there (``gap_mm``, ``gap_sigma_mm``, ``step_mm``, ``edges``, ``unmeasured``) and the
    cloud's points across it (``u_mm`` across the seam towards its second panel, ``h_mm``
    up)."""

    title: str
    seams: list[dict]
    type: Literal["cross_sections"] = "cross_sections"


@dataclass(frozen=True)
class Thumbnails:
    """Small views of findings from above their surface: per finding a ``label``, the
    half-width ``reach_mm`` and its surroundings' points (``u_mm``, ``v_mm`` in its plane,
    ``h_mm`` off it)."""

    title: str
    findings: list[dict]
    type: Literal["thumbnails"] = "thumbnails"


Panel = Annotated[
    Figures | Plot | Pictures | Table | CrossSections | Thumbnails, Field(discriminator="type")
]


@dataclass(frozen=True)
class JobFiles:
    """What a view hook is given: the job's result and its stored outputs by name."""

    result: dict
    outputs: dict[str, Path]
    """Output file name → its stored file (what the job wrote, as it named it)."""
    inputs: dict[str, Path] = field(default_factory=dict)
    """The artifacts it was given, by ``kind/name`` (``image/000000.png``: an image and its
    ground truth may share a name); a picture may show an input beside an output."""

    def inputs_of_kind(self, kind: str) -> dict[str, Path]:
        """The inputs of ``kind`` by name."""
        prefix = f"{kind}/"
        return {k.removeprefix(prefix): p for k, p in self.inputs.items() if k.startswith(prefix)}

    def json(self, name: str) -> dict | None:
        """The output ``name`` read as JSON; None when the job wrote none."""
        path = self.outputs.get(name)
        return None if path is None else json.loads(path.read_text())


View = Callable[[JobFiles], list[Figures | Plot | Pictures | Table | CrossSections | Thumbnails]]
"""A kind's view hook: its job's outputs to the panels of its run page."""


TRAINING_REPORT_NAME = "training.json"
"""The output every training kind writes its model's whole metadata to (``store_model``)."""


def training_view(files: JobFiles) -> list[Figures | Plot | Pictures]:
    """The view hook of every training kind (``contract.kinds.TRAINING_PAGE``)."""
    return training_panels(files.json(TRAINING_REPORT_NAME))


def training_panels(report: dict | None) -> list[Figures | Plot | Pictures]:
    """A trained model's run page, from its training report (the model's metadata, as
    ``contract.context.store_model`` keeps it): the loss and validation per epoch of the
    shared training loop, and the model's figures."""
    if not report:
        return []
    training = report.get("training", {})
    history = training.get("history", [])
    epochs = [float(h["epoch"]) for h in history]
    curves = [
        Line(name, epochs, [float(h[key]) for h in history])
        for key, name in (("loss", "training loss"), ("val", "validation score"))
        if history and all(key in h for h in history)
    ]
    panels: list[Figures | Plot | Pictures] = []
    if curves:
        panels.append(Plot("Training", "epoch", "loss / score (lower is better)", curves))
    figures = [
        Figure("architecture", str(report.get("architecture", "–"))),
        Figure("epochs", training.get("epochs")),
        Figure(
            "best epoch", training.get("best_epoch", report.get("metrics", {}).get("best_epoch"))
        ),
        Figure("training time", training.get("seconds"), "s"),
    ]
    for key, value in _flat(report.get("metrics", {})):
        figures.append(Figure(key, value))
    panels.append(Figures("Model", [f for f in figures if f.value is not None]))
    return panels


def result_view(files: JobFiles) -> list[Figures | Plot | Pictures]:
    """The view of a kind that declares none: the figures of the result its handler returned."""
    figures = [Figure(name, value) for name, value in _flat(files.result)]
    return [Figures("Result", figures)] if figures else []


def _flat(values: dict, prefix: str = "") -> list[tuple[str, float | int | str]]:
    """Nested figures as (dotted name, number or word) pairs; lists and None left out."""
    found = []
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            found += _flat(value, name + ".")
        elif isinstance(value, bool | int | float | str):
            found.append((name, value))
    return found
