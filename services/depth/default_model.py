"""How the depth model vista ships (``models.PACKAGED``) is built by ``vista depth
build-default``, seeded, from what this repository can reproduce:

1. simulated stereo drives of three frames (seeds 0 … ``sim_drives`` − 1, the bench's) →
   the teacher supervised by their depth: the simulator-only model;
2. that teacher adapted to a real camera by the LiDAR of a real drive (KITTI raw drive
   0052's 40 frames in ``../shared/data``: its scans through its calibration), simulated
   drives mixed in so that what the real drive lacks is not forgotten; the last epoch is
   kept (nothing real is left to choose by);
3. the student distilled from the adapted teacher on the real drive's images and simulated
   ones;
4. its weights stored in int8, one scale per output channel, computed in float
   (``onnx_io.store_weights_int8``): 3.1 MB;
5. scored on real frames it never saw — KITTI's testing frames of other drives with their
   own LiDAR depth (``../shared/data/kitti-object-testing-sample``, ten frames): Garg's crop,
   median scaling, 80 m — the figures written into its metadata with the data, the seed,
   the command and the licence (KITTI's, CC BY-NC-SA 3.0).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.depth.data import Progress
from services.depth.kinds import BuildSettings, Supervision
from services.lib.shared_data import SHARED_DATA

REAL_DRIVE = SHARED_DATA / "kitti-raw-2011_09_26"
HELD_OUT = SHARED_DATA / "kitti-object-testing-sample"
KITTI_LICENCE = (
    "Adapted with KITTI raw data (Geiger, Lenz, Stiller, Urtasun; KIT and TTI-C), licensed "
    "CC BY-NC-SA 3.0: this model is for non-commercial use, shared alike, with attribution."
)
ADAPT_LEARNING_RATE = 1e-4
"""A third of training from scratch's: the simulator's teacher is adjusted, not relearned."""


@dataclass(frozen=True)
class HeldOut:
    """Real frames with LiDAR depth, for scoring only."""

    names: list[str]
    images: list[np.ndarray]
    """(H, W, 3) uint8 at their own size."""
    truths: list[np.ndarray]
    K: list[np.ndarray]


def read_held_out(folder: Path) -> HeldOut:
    """KITTI object-benchmark frames: ``image_2/NAME.png``, ``depth/NAME.png`` (uint16 m ×
    256) and ``calib/NAME.txt`` (``P2``); ValueError naming what is missing."""
    from services.lib.images import read_image
    from services.lib.kitti import read_depth_png, read_key_values

    folder = Path(folder)
    images_dir, depth_dir = folder / "image_2", folder / "depth"
    if not images_dir.is_dir() or not depth_dir.is_dir():
        raise ValueError(f"{folder}: needs image_2/ and depth/ (KITTI object layout)")
    names = sorted(p.stem for p in images_dir.glob("*.png"))
    unmatched = [n for n in names if not (depth_dir / f"{n}.png").is_file()]
    if not names or unmatched:
        raise ValueError(f"{folder}: {len(names)} images, without depth: {unmatched[:3]}")
    Ks = []
    for name in names:
        calib = folder / "calib" / f"{name}.txt"
        Ks.append(read_key_values(calib)["P2"].reshape(3, 4)[:, :3] if calib.is_file() else None)
    return HeldOut(
        names,
        [read_image(images_dir / f"{n}.png") for n in names],
        [read_depth_png(depth_dir / f"{n}.png") for n in names],
        Ks,
    )


def score(model_path: Path, held_out: HeldOut, threads: int = 2) -> dict:
    """Monodepth2's seven metrics of a model on ``held_out`` (Garg's crop, median scaling,
    80 m), averaged over its frames, and how many frames."""
    from services.depth.metrics import evaluate_image, mean_errors
    from services.depth.models import DepthModel
    from services.depth.predict import predict_image

    model = DepthModel(model_path, threads)
    results = [
        evaluate_image(truth, predict_image(model, image)[0], crop="garg", median_scaling=True)
        for image, truth in zip(held_out.images, held_out.truths, strict=True)
    ]
    return {**mean_errors(results).to_json(), "frames": len(results)}


def _digest(folder: Path) -> str:
    """A short fingerprint of a data folder's file names and sizes."""
    listing = sorted(
        f"{p.relative_to(folder)}:{p.stat().st_size}" for p in folder.rglob("*") if p.is_file()
    )
    return hashlib.sha256("\n".join(listing).encode()).hexdigest()[:16]


def _config(settings: BuildSettings, epochs: int, **extra: object):  # noqa: ANN202 - a DepthTrainConfig
    from services.depth.training import DepthTrainConfig

    return DepthTrainConfig(
        epochs=epochs, batch=settings.batch, seed=settings.seed, threads=settings.threads, **extra
    )


def _reusable(path: Path, epochs: int) -> bool:
    """A stage's model already in the work folder, trained for as many epochs as asked."""
    from services.lib.nn.onnx_io import read_model

    if not path.is_file():
        return False
    try:
        return read_model(path).metadata.get("training", {}).get("epochs") == epochs
    except ValueError:
        return False


def simulated_drives(work: Path, count: int, size: tuple[int, int], say: Progress) -> list[Path]:
    from services.depth.camera import kitti_camera
    from services.depth.simulate import simulate_dataset

    return simulate_dataset(
        work / "sim" / "train",
        drives=count,
        frames=3,
        stereo=True,
        seed=0,
        camera=kitti_camera().resized(*size),
        progress=lambda m: say(0.0, f"simulating {m}") if m.endswith(("0", f"/{count}")) else None,
    )


def sim_teacher(
    path: Path, drives: list[Path], settings: BuildSettings, work: Path, say: Progress
) -> Path:
    """The teacher supervised by the simulated drives' depth (kept at ``path``)."""
    from services.depth.data import load_frames
    from services.depth.teacher import save_teacher, train_teacher

    if _reusable(path, settings.teacher_epochs):
        return path
    frames = load_frames(drives, *settings.size)
    config = _config(settings, settings.teacher_epochs)
    say(0.0, f"training the simulator's teacher ({config.epochs} epochs, {len(frames)} frames)")
    result = train_teacher(
        frames, "depth", config, checkpoint_dir=work / "checkpoints" / "teacher", progress=say
    )
    save_teacher(result, path, config, width=settings.size[0], height=settings.size[1])
    return path


def adapt_teacher(
    path: Path,
    teacher: Path,
    real: Path,
    sim: list[Path],
    supervision: Supervision,
    settings: BuildSettings,
    work: Path,
    say: Progress,
) -> Path:
    """``teacher`` adapted by ``supervision`` (lidar or mono) on the real drive, the
    simulated drives ``sim`` mixed in (their last one validates); the last epoch kept (kept
    at ``path``)."""
    from services.depth.data import load_frames
    from services.depth.teacher import save_teacher, train_teacher

    if _reusable(path, settings.adapt_epochs):
        return path
    folders = [real, *sim]
    frames = load_frames(folders, *settings.size, lidar=supervision == "lidar")
    config = _config(
        settings,
        settings.adapt_epochs,
        learning_rate=ADAPT_LEARNING_RATE,
        keep_best=False,
        val_groups=(len(folders) - 1,) if len(folders) > 1 else None,
    )
    say(
        0.0, f"adapting the teacher by {supervision} ({config.epochs} epochs, {len(frames)} frames)"
    )
    result = train_teacher(
        frames,
        supervision,
        config,
        initial=teacher,
        checkpoint_dir=work / "checkpoints" / f"teacher-{supervision}",
        progress=say,
    )
    save_teacher(
        result,
        path,
        config,
        width=settings.size[0],
        height=settings.size[1],
        adapted_from=teacher.name,
        real_drive=real.name,
        simulated_drives=len(sim),
    )
    return path


def distil_student(
    path: Path,
    teacher: Path,
    folders: list[Path],
    settings: BuildSettings,
    work: Path,
    say: Progress,
) -> Path:
    """The student (vista's distillation) of ``teacher`` on ``folders``' images (kept at
    ``path``; the last folder validates)."""
    from services.depth.data import load_frames
    from services.depth.distill import distill, save_student
    from services.depth.models import DepthModel

    if _reusable(path, settings.student_epochs):
        return path
    frames = load_frames(folders, *settings.size)
    config = _config(settings, settings.student_epochs, val_groups=(len(folders) - 1,))
    model = DepthModel(teacher, settings.threads)
    say(0.0, f"distilling the student ({config.epochs} epochs, {len(frames)} frames)")
    result = distill(
        model,
        frames,
        "vista",
        config,
        checkpoint_dir=work / "checkpoints" / f"student-{teacher.stem}",
        progress=say,
    )
    save_student(
        result,
        path,
        config,
        width=settings.size[0],
        height=settings.size[1],
        teacher=teacher.name,
    )
    return path


def adapted_models(
    work: Path,
    teacher: Path,
    real: Path,
    sim: list[Path],
    settings: BuildSettings,
    say: Progress,
    *,
    mono: bool = False,
) -> dict[str, Path]:
    """The teacher adapted by the real drive's LiDAR and the student distilled from it (and,
    with ``mono``, the teacher adapted by the real drive's video instead, for comparison),
    each kept in ``work``: ``{"lidar": …, "student": …, "mono": …}``."""
    out = {
        supervision: adapt_teacher(
            work / f"teacher-{supervision}.onnx",
            teacher,
            real,
            sim[: settings.adapt_sim_drives],
            supervision,
            settings,
            work,
            say,
        )
        for supervision in (("lidar", "mono") if mono else ("lidar",))
    }
    out["student"] = distil_student(
        work / "student-adapted.onnx",
        out["lidar"],
        [real, *sim[: settings.student_sim_drives]],
        settings,
        work,
        say,
    )
    return out


def _within_simulated(settings: BuildSettings) -> BuildSettings:
    """``settings`` asking for no more simulated drives in the adaptation and in the
    student's training than are simulated (the adaptation one fewer)."""
    return settings.model_copy(
        update={
            "adapt_sim_drives": min(settings.adapt_sim_drives, settings.sim_drives - 1),
            "student_sim_drives": min(settings.student_sim_drives, settings.sim_drives),
        }
    )


def build_default_model(
    out: Path,
    *,
    work: Path,
    real_drive: Path = REAL_DRIVE,
    held_out: Path = HELD_OUT,
    settings: BuildSettings = BuildSettings(),
    command: str = "vista depth build-default",
    progress: Progress | None = None,
) -> dict:
    """Build the shipped model (module docstring) into ``out``; returns its metadata. Each
    stage's result is kept in ``work`` and reused by the next run when it was trained for as
    many epochs (the stage's other settings are not compared: a new --work for those)."""
    from services.depth.models import DepthModel
    from services.lib.nn.onnx_io import METADATA_KEY, store_weights_int8

    say = progress or (lambda fraction, message: None)
    settings = _within_simulated(settings)
    for folder, what in ((real_drive, "real drive"), (held_out, "held-out frames")):
        if not Path(folder).is_dir():
            raise ValueError(f"{folder}: no such folder (the {what})")
    real_names = set(p.stem for p in (Path(real_drive) / "image_02").glob("*.png"))
    test = read_held_out(held_out)
    work.mkdir(parents=True, exist_ok=True)
    sim = simulated_drives(work, settings.sim_drives, settings.size, say)
    teacher = sim_teacher(work / "teacher.onnx", sim, settings, work, say)
    student = adapted_models(work, teacher, real_drive, sim, settings, say)["student"]
    store_weights_int8(student, out)
    say(1.0, f"scoring on {len(test.names)} held-out real frames")
    scores = {
        "shipped": score(out, test, settings.threads),
        "simulator_only_teacher": score(teacher, test, settings.threads),
    }
    model = DepthModel(out, settings.threads)
    metadata = {
        **model.spec.metadata,
        "training_data": {
            "simulated_drives": settings.sim_drives,
            "simulated_frames": 3 * settings.sim_drives,
            "real_drive": Path(real_drive).name,
            "real_frames": len(real_names),
            "real_supervision": "LiDAR scans (velodyne/ through calib.json)",
            "real_data_digest": _digest(Path(real_drive)),
        },
        "validation": {
            "held_out": Path(held_out).name,
            "frames": test.names,
            "protocol": "Garg crop, median scaling, 1e-3–80 m (monodepth2); never used in training or in any choice",
            **scores,
        },
        "weights": "int8, one scale per output channel, computed in float",
        "build": {
            "command": command,
            "seed": settings.seed,
            "settings": settings.model_dump(exclude={"threads"}),
        },
        "licence": KITTI_LICENCE,
    }
    metadata = json.loads(json.dumps(metadata))  # as the file holds it
    _write_metadata(out, metadata, METADATA_KEY)
    return metadata


def _write_metadata(path: Path, metadata: dict, key: str) -> None:
    import onnx

    proto = onnx.load_model(str(path))
    del proto.metadata_props[:]
    entry = proto.metadata_props.add()
    entry.key, entry.value = key, json.dumps(metadata, sort_keys=True)
    onnx.save_model(proto, str(path))
