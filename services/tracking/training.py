"""Training one of the tracking service's networks — what ``vista tracking train`` and the
``tracking.train`` job do: the car detector from scratch or fine-tuned from a model, or
SC3D's Siamese encoder, as ``TrainParams`` say (each network's own defaults where they
leave the passes, the step or the batch unset: ``kinds.network_defaults``)."""

from __future__ import annotations

from pathlib import Path

from services.lib.nn.fit import Progress
from services.tracking.kinds import TrainParams, network_defaults


def starting_detector(params: TrainParams, given: Path | None) -> Path | None:
    """The detector a fine-tuning starts from: ``given``, else vista's shipped one; None
    when ``params`` train from scratch. ValueError when they cannot fine-tune."""
    from services.tracking.detect_learned import DEFAULT_MODEL

    if not params.fine_tune:
        return None
    if params.network != "detector":
        raise ValueError("fine_tune applies to the detector, not to the Siamese encoder")
    if given is not None:
        if not given.is_file():
            raise ValueError(f"{given}: no such model file")
        return given
    if not DEFAULT_MODEL.is_file():
        raise ValueError(
            "this installation lacks vista's shipped detector: give the model to fine-tune"
        )
    return DEFAULT_MODEL


def train_network(
    folders: list[Path],
    out: Path,
    params: TrainParams,
    *,
    threads: int,
    start_from: Path | None = None,
    validate_on: list[Path] | None = None,
    paste_from: list[Path] | None = None,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
    sources: list[str] | None = None,
    command: str = "vista tracking train",
) -> dict:
    """Train ``params.network`` on the labelled ``folders`` (with ``fine_tune``, from
    ``start_from`` or the shipped detector), export it to ``out`` as ONNX and return its
    metadata. ``validate_on`` and ``paste_from`` are the detector's: folders held out for
    validation, folders whose cars are also pasted into the training scans."""
    from services.tracking.detector_training import DetectorTrainConfig, train_detector
    from services.tracking.siamese import SiameseTrainConfig, train_siamese

    initial = starting_detector(params, start_from)
    params = network_defaults(params)
    settings = {
        "epochs": params.epochs,
        "batch": params.batch,
        "learning_rate": params.learning_rate,
        "seed": params.seed,
        "threads": threads,
        "device": params.device,
    }
    if params.network == "detector":
        config = DetectorTrainConfig(
            **settings, window_cells=params.window, frame_step=params.frame_step,
            paste=params.paste, windows_per_epoch=params.windows,
            initial=str(initial) if initial else None,
        )  # fmt: skip
        return train_detector(
            folders, out, config, validate_on=validate_on, paste_from=paste_from,
            licence=params.licence, checkpoint_dir=checkpoint_dir, progress=progress,
            sources=sources, command=command,
        )  # fmt: skip
    if validate_on or paste_from:
        raise ValueError(
            "held-out folders and pasted cars are the detector's: the Siamese encoder "
            "validates on a share of the tracklets"
        )
    if any((Path(folder) / "label_2").is_dir() for folder in folders):
        raise ValueError(
            "the Siamese tracker learns from tracklets: give sequences with label_02, not "
            "object folders"
        )
    config = SiameseTrainConfig(**settings, samples_per_epoch=params.samples)
    return train_siamese(
        folders, out, config, licence=params.licence, checkpoint_dir=checkpoint_dir,
        progress=progress, sources=sources,
    )  # fmt: skip
