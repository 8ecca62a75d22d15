"""Training a depth network — ``vista depth train`` and the ``depth.train`` job alike
(``train_depth``): the frames of drive or image folders loaded at the training size, then
Monodepth2's network trained as a teacher (``teacher.py``, from scratch or adapting a given
teacher) or the student distilled from a given teacher (``distill.py``), as the params'
``network`` says; the model written as ONNX with its training in its metadata.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from contract.training import config_from
from contract.vocabulary import Progress
from services.depth.data import FrameSet, load_frames
from services.depth.kinds import TrainParams
from services.depth.training import DepthTrainConfig

LOADING, TRAINING, EXPORTING = 0.1, 0.95, 0.96
"""Where the progress stands when the frames are loaded, the training done, the export begun."""


@dataclass(frozen=True)
class TrainedModel:
    path: Path
    architecture: str
    metrics: dict[str, float]
    """What the model's metadata holds: a teacher's validation AbsRel (or loss), a student's
    AbsRel against its teacher."""
    frames: dict[str, int]
    """Frames that trained and that validated."""
    best_epoch: int


def train_depth(
    folders: list[Path],
    params: TrainParams,
    out: Path,
    *,
    model: Path | None = None,
    inputs: list[str] | None = None,
    model_name: str | None = None,
    threads: int = 2,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
) -> TrainedModel:
    """Train the network ``params.network`` names on the frames of ``folders`` (drive folders
    or image folders, ``data.load_frames``) and write it to ``out``. ``model``: the teacher,
    a student's to learn from (needed) or a teacher's to adapt (optional). ``inputs`` and
    ``model_name``: how the model's metadata names the data and the teacher (default the
    folders' paths, the file's name). ValueError naming what cannot be used."""
    say = progress or (lambda fraction, message: None)
    if params.network == "student" and model is None:
        raise ValueError(
            "network student needs its teacher as the model (a depth.train teacher's, or your "
            "own ONNX with vista's metadata)"
        )
    if model is not None and not Path(model).is_file():
        raise ValueError(f"{model}: no such file")
    frames = load_frames(
        folders,
        params.width,
        params.height,
        lidar=params.network == "teacher" and params.supervision == "lidar",
        progress=lambda f, m: say(LOADING * f, m),
    )
    train = _teacher if params.network == "teacher" else _student
    return train(
        frames,
        params,
        config_from(DepthTrainConfig, params, threads=threads),
        out,
        model=model,
        named={
            "inputs": inputs or [str(folder) for folder in folders],
            "model": model_name or (Path(model).name if model is not None else None),
        },
        checkpoint_dir=checkpoint_dir,
        say=say,
    )


def _training(say: Progress) -> Progress:
    return lambda f, m: say(LOADING + (TRAINING - LOADING) * f, m)


def _teacher(
    frames: FrameSet,
    params: TrainParams,
    config: DepthTrainConfig,
    out: Path,
    *,
    model: Path | None,
    named: dict,
    checkpoint_dir: Path | None,
    say: Progress,
) -> TrainedModel:
    from services.depth.teacher import TEACHER_ARCHITECTURE, save_teacher, train_teacher

    result = train_teacher(
        frames,
        params.supervision,
        config,
        initial=model,
        checkpoint_dir=checkpoint_dir,
        progress=_training(say),
    )
    say(EXPORTING, "exporting to ONNX")
    adapted = {"adapted_from": named["model"]} if model is not None else {}
    size = {"width": params.width, "height": params.height}
    metrics = save_teacher(result, out, config, **size, inputs=named["inputs"], **adapted)
    return TrainedModel(out, TEACHER_ARCHITECTURE, metrics, result.split, result.fit.best_epoch)


def _student(
    frames: FrameSet,
    params: TrainParams,
    config: DepthTrainConfig,
    out: Path,
    *,
    model: Path,
    named: dict,
    checkpoint_dir: Path | None,
    say: Progress,
) -> TrainedModel:
    from services.depth.distill import STUDENT_ARCHITECTURE, distill, save_student
    from services.depth.models import DepthModel

    teacher = DepthModel(model, config.threads)
    result = distill(
        teacher,
        frames,
        params.method,
        config,
        checkpoint_dir=checkpoint_dir,
        progress=_training(say),
    )
    say(EXPORTING, "exporting to ONNX")
    size = {"width": params.width, "height": params.height}
    metrics = save_student(
        result, out, config, **size, teacher=named["model"], inputs=named["inputs"]
    )
    return TrainedModel(out, STUDENT_ARCHITECTURE, metrics, result.split, result.fit.best_epoch)
