"""``vista depth bench``: the simulator-only models, their adaptations to a real camera and
the shipped model side by side.

1. Data: simulated stereo drives (three frames each) to train on, other simulated frames
   held out, and — where ``../shared/data`` is — KITTI raw drive 0052's 40 frames with their
   LiDAR (the adaptation drive) and KITTI's ten testing frames of other drives with LiDAR
   depth (held out: no model trains or is chosen on them).
2. Models: the teacher (Monodepth2's network, supervised by the simulator's depth) and the
   student distilled from it twice, by the thesis's L1 and by vista's method, on the same
   frames; the teacher adapted to KITTI's camera by drive 0052's LiDAR (simulated drives
   mixed in) and, separately, by its video alone (monocular, with the pose network); the
   student distilled from the LiDAR-adapted teacher on real and simulated images
   (``default_model``); the model vista ships. Each is trained here unless already in the
   work folder (a rerun reuses them).
3. Accuracy: monodepth2's seven metrics on the held-out simulated frames (metric, no crop)
   and on the real frames (Garg's crop, median scaling, 80 m cap), for each model, the
   student in int8 (calibrated on the frames it predicts) and a flat-road prior with no
   learning.
4. Latency per 1024 × 320 frame on 1 and 2 threads: torch eager, onnxruntime fp32, int8
   (QDQ and QOperator).

The thesis's figures (Tables 5.2–5.3, KITTI Eigen split, i7-5820K) are printed beside.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.bench import print_verdict, say, write_document
from services.depth.camera import kitti_camera
from services.depth.data import FrameSet, load_frames
from services.depth.distill import METHODS
from services.depth.drive import read_drive
from services.depth.kinds import BuildSettings
from services.depth.metrics import METRICS, evaluate_image, mean_errors
from services.depth.models import PACKAGED, DepthModel
from services.depth.training import DepthTrainConfig
from services.lib.images import read_image
from services.lib.kitti import read_depth_png
from services.lib.process import available_cores, prepare_process

BUILD = BuildSettings()
"""The shipped model's build: the bench trains at its size, on as many drives, as long."""
TRAIN_SIZE = BUILD.size
LATENCY_SIZE = (1024, 320)
TRAIN_DRIVES, TEST_FRAMES = BUILD.sim_drives, 120
TEST_SEED = 900_000
"""Held-out drives' seeds: far from the training drives' 0 … TRAIN_DRIVES."""
SIM_SET = "simulated, held out"
HELD_OUT_SET = "KITTI real, held out (10 testing frames of other drives)"
ADAPTATION_SET = "KITTI real drive 0052 (the adaptation drive: seen in training)"
TEACHER_EPOCHS, STUDENT_EPOCHS = BUILD.teacher_epochs, BUILD.student_epochs
LATENCY_RUNS = 10
THESIS = {
    "student": {
        "parameters": 2_643_281,
        "s_1_core": 0.4231,
        "s_6_cores": 0.1445,
        "abs_rel": 0.110,
        "rmse": 5.139,
        "delta1": 0.863,
    },
    "teacher": {
        "parameters": 14_849_936,
        "s_1_core": 0.7365,
        "s_6_cores": 0.2611,
        "abs_rel": 0.105,
        "rmse": 4.608,
        "delta1": 0.876,
    },
}
TARGETS = {
    "student_parameters": 2_700_000,
    "student_fp32_s_2_threads": 0.12,
    "student_int8_s_2_threads": 0.07,
    "student_abs_rel_over_teacher": 1.05,
    "real_abs_rel": 0.20,
    "int8_speedup": 1.5,
}
SHIPPED = "shipped default (student, int8 weights)"


@dataclass(frozen=True)
class EvalSet:
    name: str
    images: list[np.ndarray]
    """(H, W, 3) uint8 each, at their own size."""
    truths: list[np.ndarray]
    crop: str
    median_scaling: bool
    K: np.ndarray
    """Intrinsics at the images' size (for the flat-road prior)."""


def _sim_data(work: Path, drives: int, test_frames: int) -> tuple[list[Path], list[Path]]:
    from services.depth.simulate import simulate_dataset

    camera = kitti_camera().resized(*TRAIN_SIZE)
    say(f"simulating {test_frames} held-out frames and {drives} training drives (kept in {work})")
    test = simulate_dataset(
        work / "sim" / "test",
        drives=test_frames,
        frames=1,
        stereo=False,
        seed=TEST_SEED,
        camera=camera,
    )
    train = simulate_dataset(
        work / "sim" / "train",
        drives=drives,
        frames=3,
        stereo=True,
        seed=0,
        camera=camera,
        progress=lambda m: say(m) if m.endswith("00/" + str(drives)) else None,
    )
    return train, test


def _teacher(path: Path, frames: FrameSet, config: DepthTrainConfig, work: Path) -> None:
    from services.depth.teacher import save_teacher, train_teacher

    say(
        f"training the teacher ({config.epochs} epochs on {len(frames)} frames, supervised by depth)"
    )
    checkpoints = work / "checkpoints" / "teacher"
    result = train_teacher(
        frames, "depth", config, checkpoint_dir=checkpoints, progress=lambda f, m: say(m)
    )
    save_teacher(result, path, config, width=TRAIN_SIZE[0], height=TRAIN_SIZE[1])


def _students(
    work: Path, teacher_path: Path, frames: FrameSet, config: DepthTrainConfig
) -> dict[str, Path]:
    from services.depth.distill import distill, save_student, teacher_targets

    paths = {method: work / f"student-{method}.onnx" for method in METHODS}
    missing = [m for m, p in paths.items() if not p.is_file()]
    if not missing:
        return paths
    teacher = DepthModel(teacher_path, available_cores())
    say(f"running the teacher on {len(frames)} training frames and their mirror images")
    targets = teacher_targets(teacher, frames, features=True)
    for method in missing:
        say(f"distilling the student by the {method} method ({config.epochs} epochs)")
        checkpoints = work / "checkpoints" / f"student-{method}"
        result = distill(
            teacher,
            frames,
            method,
            config,
            checkpoint_dir=checkpoints,
            progress=lambda f, m: say(m),
            targets=targets,
        )
        architecture = teacher.spec.metadata.get("architecture", teacher_path.name)
        save_student(
            result,
            paths[method],
            config,
            width=TRAIN_SIZE[0],
            height=TRAIN_SIZE[1],
            teacher=architecture,
        )
    return paths


def _eval_sets(test_drives: list[Path]) -> list[EvalSet]:
    from services.depth.default_model import HELD_OUT, REAL_DRIVE, read_held_out

    sets = []
    images, truths = [], []
    for folder in test_drives:
        drive = read_drive(folder)
        images.append(read_image(drive.left[0]))
        truths.append(read_depth_png(drive.depth[0]))
    K = kitti_camera().resized(*TRAIN_SIZE).K
    sets.append(EvalSet(SIM_SET, images, truths, "none", False, K))
    if HELD_OUT.is_dir():
        held_out = read_held_out(HELD_OUT)
        sets.append(
            EvalSet(
                HELD_OUT_SET,
                held_out.images,
                held_out.truths,
                "garg",
                True,
                held_out.K[0] if held_out.K[0] is not None else kitti_camera().K,
            )
        )
    if REAL_DRIVE.is_dir():
        drive = read_drive(REAL_DRIVE)
        pairs = [
            (p, d) for p, d in zip(drive.left, drive.depth or (), strict=False) if d is not None
        ]
        sets.append(
            EvalSet(
                ADAPTATION_SET,
                [read_image(p) for p, _ in pairs],
                [read_depth_png(d) for _, d in pairs],
                "garg",
                True,
                drive.camera.K,
            )
        )
    return sets


def flat_road(
    image: np.ndarray, K: np.ndarray, height_m: float = 1.65, far_m: float = 40.0
) -> np.ndarray:
    """The no-learning prior: the road plane below the horizon, ``far_m`` above it."""
    rows = np.arange(image.shape[0], dtype=np.float64)[:, None]
    below = rows - K[1, 2]
    depth = np.where(below > 0, height_m * K[1, 1] / np.maximum(below, 1e-9), far_m)
    return np.broadcast_to(np.minimum(depth, far_m), image.shape[:2]).astype(np.float32)


def _score(predict, evalset: EvalSet) -> dict:  # noqa: ANN001 - image → depth at its size
    results = [
        evaluate_image(
            truth, predict(image), crop=evalset.crop, median_scaling=evalset.median_scaling
        )
        for image, truth in zip(evalset.images, evalset.truths, strict=True)
    ]
    return mean_errors(results).to_json()


def _accuracy(models: dict[str, Path], evalsets: list[EvalSet], work: Path) -> dict:
    from services.depth.predict import predict_image, resize_for
    from services.depth.quantize import quantize_int8

    out: dict[str, dict] = {}
    for evalset in evalsets:
        say(f"accuracy on {evalset.name} ({len(evalset.images)} frames)")
        rows = {"flat-road prior": _score(lambda image, K=evalset.K: flat_road(image, K), evalset)}
        for name, path in models.items():
            model = DepthModel(path, available_cores())
            rows[name] = _score(lambda image, m=model: predict_image(m, image)[0], evalset)
            if not name.startswith(("student-vista", "student of")):
                continue
            sample = np.stack([resize_for(model, image) for image in evalset.images])
            tag = evalsets.index(evalset)
            for form, operators in (("QDQ", False), ("QOperator", True)):
                int8 = DepthModel(
                    quantize_int8(
                        model, sample, work / f"{path.stem}.{form}-{tag}.onnx", operators=operators
                    ),
                    available_cores(),
                )
                try:
                    rows[f"{name} int8 {form}"] = _score(
                        lambda image, m=int8: predict_image(m, image)[0], evalset
                    )
                except ValueError as exc:  # no valid depth: unmeasured, said why
                    say(f"{name} int8 {form} on {evalset.name}: unmeasured ({exc})")
                    rows[f"{name} int8 {form}"] = {m: None for m in METRICS}
        out[evalset.name] = rows
    return out


def _median_seconds(run, runs: int) -> float:  # noqa: ANN001 - a callable
    run()
    times = []
    for _ in range(runs):
        started = time.perf_counter()
        run()
        times.append(time.perf_counter() - started)
    return float(np.median(times))


def _latency(calibration: list[np.ndarray], work: Path, runs: int) -> dict:
    """Seconds per 1024 × 320 frame for each network, runtime and thread count."""
    import cv2
    import torch

    from services.depth.export import export_depth_model
    from services.depth.nets import Student, Teacher, parameters
    from services.depth.quantize import quantize_int8

    width, height = LATENCY_SIZE
    frames = np.stack(
        [cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA) for image in calibration]
    )
    table: dict[str, dict] = {}
    for name, network in (("student", Student()), ("teacher", Teacher())):
        say(f"latency of the {name} at {width} × {height}")
        network.eval()
        fp32 = work / f"latency-{name}.onnx"
        export_depth_model(network, fp32, width=width, height=height, architecture=name)
        int8 = quantize_int8(DepthModel(fp32, 1), frames, work / f"latency-{name}.int8.onnx")
        int8op = quantize_int8(
            DepthModel(fp32, 1), frames, work / f"latency-{name}.int8op.onnx", operators=True
        )
        row: dict[str, float | int] = {"parameters": parameters(network)}
        x = torch.from_numpy(frames[:1].transpose(0, 3, 1, 2).astype(np.float32) / 255)
        for threads in (1, 2):
            torch.set_num_threads(threads)
            with torch.no_grad():
                row[f"torch_s_{threads}"] = _median_seconds(lambda n=network, x=x: n(x), runs)
            for kind, path in (("fp32", fp32), ("int8", int8), ("int8op", int8op)):
                model = DepthModel(path, threads)
                row[f"{kind}_s_{threads}"] = _median_seconds(
                    lambda m=model: m.predict(frames[:1]), runs
                )
        table[name] = row
    torch.set_num_threads(available_cores())
    return table


def _print_tables(accuracy: dict, latency: dict) -> None:
    for setname, rows in accuracy.items():
        print(f"\n### Accuracy: {setname}\n")
        print("| model | " + " | ".join(METRICS) + " |")
        print("|---|" + "---|" * len(METRICS))
        for name, metrics in rows.items():
            cells = ["unmeasured" if metrics[m] is None else f"{metrics[m]:.3f}" for m in METRICS]
            print(f"| {name} | " + " | ".join(cells) + " |")
    print("\n| thesis, KITTI Eigen (Table 5.2) | abs_rel | rmse | delta1 |\n|---|---|---|---|")
    for name, figures in THESIS.items():
        print(
            f"| {name} | {figures['abs_rel']:.3f} | {figures['rmse']:.3f} | {figures['delta1']:.3f} |"
        )
    print(f"\n### Latency per {LATENCY_SIZE[0]} × {LATENCY_SIZE[1]} frame, seconds\n")
    print(
        "| network | parameters | torch 1 | torch 2 | ORT fp32 1 | ORT fp32 2 | ORT int8 QDQ 1 | ORT int8 QDQ 2 | ORT int8 QOperator 1 | ORT int8 QOperator 2 | thesis 1 core | thesis 6 cores |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, row in latency.items():
        thesis = THESIS[name]
        cells = [
            f"{row[f'{kind}_s_{threads}']:.3f}"
            for kind in ("torch", "fp32", "int8", "int8op")
            for threads in (1, 2)
        ]
        print(
            f"| {name} | {row['parameters'] / 1e6:.2f} M | "
            + " | ".join(cells)
            + f" | {thesis['s_1_core']:.3f} | {thesis['s_6_cores']:.3f} |"
        )


def _adapted(work: Path, teacher: Path, sim: list[Path], batch: int) -> dict[str, Path]:
    """The simulator's teacher adapted to KITTI's camera by drive 0052's LiDAR and by its
    video, and the student of the LiDAR-adapted one (``default_model``'s stages)."""
    from services.depth.default_model import REAL_DRIVE, adapted_models

    if not REAL_DRIVE.is_dir():
        return {}
    settings = BuildSettings(sim_drives=len(sim), batch=batch, threads=available_cores())
    models = adapted_models(
        work, teacher, REAL_DRIVE, sim, settings, lambda f, m: say(m), mono=True
    )
    return {
        "teacher, adapted by drive 0052's LiDAR": models["lidar"],
        "teacher, adapted by drive 0052's video (mono)": models["mono"],
        "student of the LiDAR-adapted teacher (fp32)": models["student"],
    }


def _verdict(accuracy: dict, latency: dict) -> dict[str, bool]:
    sim = accuracy[SIM_SET]
    student = latency["student"]
    int8_best = min(student["int8_s_2"], student["int8op_s_2"])
    verdict = {
        f"student ≤ {TARGETS['student_parameters'] / 1e6:.1f} M parameters": student["parameters"]
        <= TARGETS["student_parameters"],
        f"student fp32 ≤ {TARGETS['student_fp32_s_2_threads']} s on 2 threads": student["fp32_s_2"]
        <= TARGETS["student_fp32_s_2_threads"],
        f"student int8 ≤ {TARGETS['student_int8_s_2_threads']} s on 2 threads": int8_best
        <= TARGETS["student_int8_s_2_threads"],
        f"student int8 ≥ {TARGETS['int8_speedup']}× faster than fp32 on 2 threads (QDQ or QOperator)": student[
            "fp32_s_2"
        ]
        >= TARGETS["int8_speedup"] * int8_best,
        "student (vista) AbsRel within 5 % of the teacher's, held-out simulated": sim[
            "student-vista (simulator only)"
        ]["abs_rel"]
        <= TARGETS["student_abs_rel_over_teacher"] * sim["teacher (simulator only)"]["abs_rel"],
        "vista's distillation better than the thesis's L1 (AbsRel, held-out simulated)": sim[
            "student-vista (simulator only)"
        ]["abs_rel"]
        < sim["student-thesis (simulator only)"]["abs_rel"],
    }
    for setname, rows in accuracy.items():
        fp32 = rows.get("student of the LiDAR-adapted teacher (fp32)")
        fast = rows.get("student of the LiDAR-adapted teacher (fp32) int8 QOperator")
        if fp32 and fast:
            verdict[f"int8 (QOperator) within 5 % of fp32's AbsRel, {setname}"] = (
                fast["abs_rel"] is not None and fast["abs_rel"] <= 1.05 * fp32["abs_rel"]
            )
    real = accuracy.get(HELD_OUT_SET, {})
    if SHIPPED in real:
        verdict[f"shipped model AbsRel ≤ {TARGETS['real_abs_rel']} on held-out real frames"] = (
            real[SHIPPED]["abs_rel"] <= TARGETS["real_abs_rel"]
        )
    for name, row in real.items():
        if "adapted" in name and " int8 " not in name:
            verdict[f"{name} better than the simulator-only teacher (held-out real)"] = (
                row["abs_rel"] < real["teacher (simulator only)"]["abs_rel"]
            )
    return verdict


def run_depth_bench(
    out: Path,
    *,
    work: Path,
    teacher: Path | None,
    train_drives: int = TRAIN_DRIVES,
    teacher_epochs: int = TEACHER_EPOCHS,
    student_epochs: int = STUDENT_EPOCHS,
    test_frames: int = TEST_FRAMES,
    latency_runs: int = LATENCY_RUNS,
    batch: int = BUILD.batch,
) -> dict:
    """The whole bench (module docstring); returns the JSON document it writes."""
    prepare_process()
    work.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    train_drives_paths, test_drives = _sim_data(work, train_drives, test_frames)
    frames = None
    teacher_path = teacher or work / "teacher.onnx"
    students_ready = all((work / f"student-{m}.onnx").is_file() for m in METHODS)
    if not teacher_path.is_file() or not students_ready:
        frames = load_frames(train_drives_paths, *TRAIN_SIZE)
    if not teacher_path.is_file():
        _teacher(
            teacher_path,
            frames,
            DepthTrainConfig(epochs=teacher_epochs, batch=batch, threads=available_cores()),
            work,
        )
    students_config = DepthTrainConfig(
        epochs=student_epochs, batch=batch, threads=available_cores()
    )
    students = (
        _students(work, teacher_path, frames, students_config)
        if frames is not None
        else {m: work / f"student-{m}.onnx" for m in METHODS}
    )
    models = {
        "teacher (simulator only)": teacher_path,
        "student-thesis (simulator only)": students["thesis"],
        "student-vista (simulator only)": students["vista"],
        **_adapted(work, teacher_path, train_drives_paths, batch),
    }
    if PACKAGED.is_file():
        models[SHIPPED] = PACKAGED
    evalsets = _eval_sets(test_drives)
    accuracy = _accuracy(models, evalsets, work)
    latency = _latency(evalsets[-1].images, work, latency_runs)
    _print_tables(accuracy, latency)
    verdict = _verdict(accuracy, latency)
    metadata = {name: DepthModel(path).spec.metadata for name, path in models.items()}
    document = write_document(
        out,
        bench="depth",
        targets=TARGETS,
        thesis=THESIS,
        accuracy=accuracy,
        latency=latency,
        models={
            name: {
                k: v
                for k, v in meta.items()
                if k in ("architecture", "parameters", "training", "metrics")
            }
            for name, meta in metadata.items()
        },
        seconds=round(time.perf_counter() - started, 1),
        verdict=verdict,
    )
    print_verdict(verdict, out)
    return document
