"""A job kind as data: its name (``<service>.<verb>``, older names as aliases), queue,
handler, parameters, what it reads and writes, and how its results appear in the scene.

A service lists its kinds in ``KINDS`` in its ``kinds`` module; the supervisor's registry
collects them. Handlers and presenters are named by import path and imported only where
they run (a handler inside a worker), so the API process never loads a service's heavy
libraries.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from contract.scene import Present, SceneHook
from contract.views import View

ANY_KIND = "*"


@dataclass(frozen=True)
class Inputs:
    """How many artifacts of these kinds one step of a job kind reads."""

    kinds: tuple[str, ...]
    what: str
    """What they are, for people: "the stitched point cloud"."""
    min: int = 1
    max: int | None = 1
    """``None``: no upper limit."""
    needed_when: tuple[str, tuple[str, ...]] | None = None
    """(parameter, values): with the parameter at one of the values at least one is needed
    (an OE-Net model for ``method: oenet``), whatever ``min`` says."""
    only_when: tuple[str, tuple[str, ...]] | None = None
    """(parameter, values): with the parameter at any other value none may be given."""
    made_by: tuple[str, ...] | None = None
    """The job kinds whose output this is, when not every kind writing files of these kinds
    makes one (a depth map's camera-frame cloud is no stitched panel cloud); None: all."""

    def accepts(self, kind: str) -> bool:
        return ANY_KIND in self.kinds or kind in self.kinds


@dataclass(frozen=True)
class Output:
    """An artifact a job kind writes; ``per_input`` ones are written once per input, their
    ``name`` a template with ``{stem}`` (the input's name without its suffix)."""

    kind: str
    name: str
    per_input: bool = False

    def file_name(self, stem: str = "") -> str:
        return self.name.format(stem=stem)


@dataclass(frozen=True)
class Presenter:
    """A job kind's results in the inspection's scene: ``hook`` (``module:function``, a
    ``contract.scene.Present``) draws the newest ``reads`` output of the inspection over
    the points of the input it read of kind ``over``, with the inspection's files of the
    kinds ``surfaces`` (PLY triangle meshes) beside them."""

    reads: Output
    hook: str
    over: str = "cloud"
    """The artifact kind of the input drawn as points beneath the lines."""
    surfaces: tuple[str, ...] = ()
    """Artifact kinds drawn as surfaces (the nominal panels of a measurement, a part's
    nominal model)."""
    points: Output | None = None
    """An output drawn as the points instead of the input it read (a comparison's scan,
    aligned to its nominal and coloured by its deviation); None: the input."""

    def load(self) -> Present:
        return load_hook(self.hook)


@dataclass(frozen=True)
class Presentation:
    """How a kind's results are shown, declared in one place and read by every client:
    ``page`` (``module:function``, a ``contract.views.View``: its run page's figures,
    plots and pictures from its stored outputs; None: the outputs' list only), ``scene``
    (``module:function``, a ``contract.scene.SceneHook``: its results in 3D, served as
    glTF at ``GET /jobs/{id}/scene.glb`` for the dashboard, the headset and Unity) and
    ``inspection`` (its lines in the inspection's scene, a ``Presenter``)."""

    page: str | None = None
    scene: str | None = None
    inspection: Presenter | None = None

    def load_page(self) -> View | None:
        return None if self.page is None else load_hook(self.page)

    def load_scene(self) -> SceneHook | None:
        return None if self.scene is None else load_hook(self.scene)


TRAINING_PAGE = Presentation(page="contract.views:training_view")
"""Every training kind's run page: its history and its model's metadata."""


@dataclass(frozen=True)
class JobKind:
    name: str
    queue: str
    handler: str
    """``module:function`` taking a ``JobContext`` and returning a JSON-able dict (the
    job's result). A ``warning`` key in it (a sentence) is what the job could not do and a
    person must know: the job still succeeds, but its message, its API record
    (``warning``), its run and the dashboard say so instead of a plain "done"."""
    params: type[BaseModel]
    description: str
    inputs: tuple[Inputs, ...] = ()
    """What the handler reads: checked when a run is created."""
    outputs: tuple[Output, ...] = ()
    """What it writes (the handler takes the names from here): a later step's inputs are
    checked against them, and ``GET /job-kinds`` lists them."""
    shows: Presentation = Presentation()
    """How its results are shown: its run page, its own 3D scene, and its part of the
    inspection's scene — one declaration."""
    aliases: tuple[str, ...] = ()
    """Older names still accepted (scripts, stored runs): a step given one runs this kind
    and is stored under ``name``."""

    @property
    def input_kinds(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(k for spec in self.inputs for k in spec.kinds))

    def load_handler(self) -> Callable[[Any], dict]:
        return load_hook(self.handler)


def load_hook(path: str) -> Any:
    """The function ``module:function`` names, its module imported now (hooks are named
    by path so that declaring a kind loads none of a service's libraries)."""
    module_name, _, function = path.partition(":")
    return getattr(importlib.import_module(module_name), function)
