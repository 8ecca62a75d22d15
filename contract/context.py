"""What a job handler sees: its parameters and inputs, progress, cancellation, outputs.

``JobContext`` is a protocol: the supervisor's engine gives handlers an object that has
these members, and a test may give them any other.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, TypeVar

from pydantic import BaseModel

from contract.errors import JobInputError
from contract.kinds import Output
from contract.tolerances import Tolerances
from contract.vocabulary import ONNX_MEDIA_TYPE, DefectType, Severity

Unpacked = TypeVar("Unpacked")


@dataclass(frozen=True)
class InputArtifact:
    id: int
    kind: str
    name: str
    media_type: str
    path: Path
    meta: dict
    job_id: int | None

    @property
    def label(self) -> str:
        """How messages name it: "artifact 18 (spray.ply)" (never its storage path)."""
        return f"artifact {self.id} ({self.name})"


@dataclass(frozen=True)
class NewDefect:
    """A finding a job reports; lengths in mm, ``normal`` a unit vector."""

    type: DefectType
    location_mm: tuple[float, float, float]
    normal: tuple[float, float, float]
    value_mm: float | None
    tolerance_mm: float | None
    extent_mm: float
    severity: Severity
    confidence: float
    measurements: dict = field(default_factory=dict)


class JobContext(Protocol):
    kind: str
    """The job kind's name."""
    params: BaseModel
    """The parameters, validated against the kind's model."""
    attempt: int
    """1 for the first attempt."""
    tolerances: Tolerances
    """The inspection's acceptance limits when the job was claimed."""
    threads: int
    """Threads the handler's algorithms may run on (the worker's setting)."""
    inputs: tuple[InputArtifact, ...]

    @property
    def workdir(self) -> Path:
        """A scratch folder for this attempt, removed when it ends."""
        ...

    def progress(self, fraction: float, message: str = "") -> None:
        """Report progress (0..1); raises ``JobCancelled`` once cancellation was asked."""
        ...

    def check_cancelled(self) -> None: ...

    def add_artifact_file(
        self, path: Path, *, kind: str, name: str, media_type: str, meta: dict | None = None
    ) -> None:
        """Stage a file as an output; it is kept only if the attempt succeeds."""
        ...

    def add_artifact_json(self, data: dict, *, kind: str, name: str) -> None: ...

    def add_defect(self, defect: NewDefect) -> None: ...


def inputs_of_kind(ctx: JobContext, *kinds: str) -> list[InputArtifact]:
    return [a for a in ctx.inputs if a.kind in kinds]


def one_input(ctx: JobContext, kind: str, what: str) -> InputArtifact:
    """The one input of ``kind``; anything else is the standard ``JobInputError``."""
    found = inputs_of_kind(ctx, kind)
    if len(found) != 1:
        names = ", ".join(a.name for a in found) or "none"
        raise JobInputError(f"{ctx.kind} needs exactly one `{kind}` artifact ({what}); got {names}")
    return found[0]


def input_error(artifact: InputArtifact, exc: Exception) -> JobInputError:
    """The file's error, naming the artifact instead of its storage path."""
    return JobInputError(str(exc).replace(str(artifact.path), artifact.label))


def in_user_words(message: str, ctx: JobContext, artifacts: list[InputArtifact]) -> str:
    """An error about files the job unpacked or read, in the user's words: each input's
    storage path becomes its label, the scratch folder "the job's folder"."""
    for artifact in artifacts:
        message = message.replace(str(artifact.path), artifact.label)
    return message.replace(str(ctx.workdir), "the job's folder")


def unpacked(
    artifact: InputArtifact, folder: Path, extract: Callable[[Path, Path], Unpacked]
) -> Unpacked:
    """An archive input unpacked into ``folder`` by ``extract``; its refusal (a
    ``ValueError``) is the job's, naming the artifact."""
    try:
        return extract(artifact.path, folder)
    except ValueError as exc:
        raise JobInputError(f"{artifact.label}: {exc}") from exc


def store_model(
    ctx: JobContext, path: Path, metadata: dict, *, model: Output, report: Output
) -> None:
    """A trained network kept as the ``model`` output (ONNX; its architecture, scores and
    size as the artifact's metadata) and its whole metadata — data, settings, each epoch's
    losses — as the ``report`` output."""
    summary = ("architecture", "metrics", "parameters")
    ctx.add_artifact_file(
        path,
        kind=model.kind,
        name=path.name,
        media_type=ONNX_MEDIA_TYPE,
        meta={key: metadata[key] for key in summary if key in metadata},
    )
    ctx.add_artifact_json(metadata, kind=report.kind, name=report.file_name())
