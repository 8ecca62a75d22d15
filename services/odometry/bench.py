"""``vista odometry bench``: the three methods on the same simulated frames, against truth.

1. The thesis-like set: the 28.578 m circuit at 60 fps over concrete (thesis 6.3.3), each
   method's per-step RMSE, final error, ATE, drift, flagged pairs and pairs/s on this
   machine's cores; OE-Net also by the thesis's own protocol (the RMSE on the random 10 %
   of its training pairs it never trained on nor was chosen by).
2. A sweep: every floor (the procedural ones, scikit-image's pictures, one picture no
   model here was trained on and, where ``../shared/data`` is, a real KITTI camera frame),
   speeds 0.2–2 m/s, turns on the spot and fast arcs, motion
   blur, changing light and a moving shadow, the camera's height changing ± 5 mm.
3. Real photographs as floors: KITTI camera frames of other drives (whole, and their road
   cropped) and scikit-image's photographs, each pixel covering 0.1, 0.3 or 1 mm of floor
   (texels finer and coarser than the camera's 0.24 mm pixels), driven along a 5.8 m path
   with S-bends and a 90° turn at 0.4 m/s; and a straight 8 s run over a KITTI frame, whose
   heading should not turn.

Each case reports the heading's bias (its mean per-frame error) and, for vista's method,
the final pose's error against its covariance: the NEES (about 3 on average when the
covariance tells the truth) and whether the position error is within 2σ.

OE-Net is trained here, as ``vista odometry train`` does, on four circuits over other
concrete floors (seeds 1–4: about 12 000 pairs, the thesis's 10 k), unless a model is
given; the model is kept, so the next run reuses it.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from contract.bench import print_verdict, say, write_document
from services.lib.process import available_cores, prepare_process
from services.lib.shared_data import SHARED_DATA
from services.odometry.camera import FloorCamera
from services.odometry.drive import Command
from services.odometry.evaluate import evaluate
from services.odometry.floors import PROCEDURAL, SAMPLE_IMAGES
from services.odometry.kinds import METHODS, OdometryParams, TrainParams
from services.odometry.render import Effects
from services.odometry.run import run_odometry
from services.odometry.simulate import simulate_sequence
from services.odometry.tum import read_tum

UNSEEN_FLOOR = "moon"
"""scikit-image's lunar surface picture: used by no model here in training."""
KITTI_FLOOR = "KITTI street photo"
KITTI_FRAME = SHARED_DATA / "kitti-raw-2011_09_26/image_02/0000000000.png"
KITTI_OTHER_DRIVES = SHARED_DATA / "kitti-object-testing-sample/image_2"
ROAD_CROP = (200, 375, 0, 1242)
"""Rows and columns of a KITTI frame that are road."""
"""A real camera's frame (KITTI, CC BY-NC-SA 3.0) as a floor: a real sensor's texture and
noise, road, cars and a nearly plain sky; in the sweep where the shared data is present."""
TRAINING_SEEDS = (1, 2, 3, 4)
TARGETS = {
    "oenet_rmse_dxy_mm": 0.13,
    "oenet_rmse_dtheta_deg": 1.0,
    "vista_rmse_dxy_mm": 0.03,
    "vista_rmse_dtheta_deg": 0.05,
    "vista_final_error_m": 0.03,
    "vista_drift_percent_every_floor": 0.2,
    "vista_pairs_per_s": 300,
    "vista_times_the_peer": 6.0,
    "vista_drift_percent_real_photos": 0.2,
    "vista_heading_bias_deg_per_frame": 0.0002,
    "vista_share_within_2_sigma": 0.9,
}


@dataclass(frozen=True)
class Case:
    name: str
    group: str
    floor: str = "concrete"
    path: str = "random"
    seconds: float = 6.0
    commands: tuple[Command, ...] | None = None
    effects: Effects = field(default_factory=Effects)
    seed: int = 0
    floor_mm_per_px: float = 0.3
    """How much floor an image floor's pixel covers."""
    crop: tuple[int, int, int, int] | None = None
    """Rows and columns of the image floor to keep (first row, last, first column, last)."""

    def document(self) -> dict:
        return {
            "name": self.name,
            "group": self.group,
            "floor": self.floor,
            "floor_mm_per_px": self.floor_mm_per_px,
            "crop": list(self.crop) if self.crop else None,
            "path": self.path,
            "commands": [asdict(c) for c in self.commands] if self.commands else None,
            "seconds": self.seconds,
            "effects": asdict(self.effects),
            "seed": self.seed,
        }


def _cruise(speed_mm_s: float, seconds: float = 4.0) -> tuple[Command, ...]:
    """Up to ``speed_mm_s`` and on with a gentle S-bend."""
    third = seconds / 3
    return (
        Command(third, speed_mm_s, 20.0),
        Command(third, speed_mm_s, -20.0),
        Command(third, speed_mm_s, 0.0),
    )


LOOP = Case("thesis-like circuit 28.6 m", "loop", path="loop", seconds=0.0)
FLOORS = tuple(
    Case(f"floor {name}", "floor", floor=name)
    for name in (
        *PROCEDURAL,
        *SAMPLE_IMAGES,
        UNSEEN_FLOOR,
        *((KITTI_FLOOR,) if KITTI_FRAME.is_file() else ()),
    )
)
REAL_PATH = (
    Command(2.5, 400.0),
    Command(2.0, 400.0, 45.0),
    Command(2.0, 400.0, -45.0),
    Command(2.0, 400.0),
    Command(2.0, 400.0, 45.0),
    Command(4.0, 400.0),
)
"""5.8 m at 0.4 m/s with an S-bend and a 90° turn (straights between)."""


def _real_photos() -> tuple[Case, ...]:
    """Real photographs as floors at texels finer than, about and coarser than the pixels."""
    cases = []
    if KITTI_OTHER_DRIVES.is_dir():
        frames = sorted(KITTI_OTHER_DRIVES.glob("*.png"))
        for frame, scale in zip(frames[:3], (0.1, 0.3, 1.0), strict=False):
            cases.append(
                Case(f"photo KITTI {frame.stem} at {scale} mm/px", "photo", floor=str(frame),
                     commands=REAL_PATH, floor_mm_per_px=scale)
            )  # fmt: skip
        for frame in frames[3:5]:
            cases.append(
                Case(f"photo KITTI {frame.stem} road at 0.3 mm/px", "photo", floor=str(frame),
                     commands=REAL_PATH, crop=ROAD_CROP)
            )  # fmt: skip
        cases.append(
            Case("straight on KITTI 000000 at 0.1 mm/px", "straight", floor=str(frames[0]),
                 commands=(Command(8.0, 400.0),), floor_mm_per_px=0.1)
        )  # fmt: skip
    for name, scale in (("gravel", 0.1), ("brick", 1.0), ("grass", 0.1), (UNSEEN_FLOOR, 0.1)):
        cases.append(
            Case(f"photo {name} at {scale} mm/px", "photo", floor=name, commands=REAL_PATH,
                 floor_mm_per_px=scale)
        )  # fmt: skip
    return tuple(cases)


SWEEP = (
    *FLOORS,
    *_real_photos(),
    *(
        Case(f"speed {v:.1f} m/s", "speed", commands=_cruise(v * 1000))
        for v in (0.2, 0.6, 1.0, 1.5, 2.0)
    ),
    Case("spin 90°/s", "turn", commands=(Command(4.0, 0.0, 90.0),)),
    Case("spin 180°/s", "turn", commands=(Command(3.0, 0.0, -180.0),)),
    Case("arc 1 m/s at 120°/s", "turn", commands=(Command(3.0, 1000.0, 120.0),)),
    Case("blur: 4 ms at 1 m/s", "blur", commands=_cruise(1000.0), effects=Effects(exposure_ms=4.0)),
    Case("blur: 8 ms at 1 m/s", "blur", commands=_cruise(1000.0), effects=Effects(exposure_ms=8.0)),
    Case("light ± 30 %", "light", effects=Effects(gain_swing=0.3)),
    Case("moving shadow 60 %", "light", effects=Effects(shadow=0.6)),
    Case("height ± 5 mm", "height", effects=Effects(height_swing_mm=5.0)),
    Case("noise × 3", "noise", effects=Effects(noise=3.0)),
)


def _floor_source(name: str) -> str:
    if name == UNSEEN_FLOOR:
        from skimage import data

        return str(Path(data.__file__).parent / "moon.png")
    if name == KITTI_FLOOR:
        return str(KITTI_FRAME)
    return name


def _cropped(source: str, crop: tuple[int, int, int, int], folder: Path) -> str:
    """The image floor cut to ``crop``, written beside the case's frames."""
    import cv2

    first_row, last_row, first_col, last_col = crop
    image = cv2.imread(source, cv2.IMREAD_UNCHANGED)[first_row:last_row, first_col:last_col]
    path = folder / "floor.png"
    cv2.imwrite(str(path), image)
    return str(path)


def _sequence(case: Case, work: Path) -> Path:
    """The case's frames with their truth, simulated once (kept in ``work``)."""
    folder = work / case.name.replace(" ", "-").replace("/", "-")
    stamp = folder / "case.json"
    if stamp.exists() and json.loads(stamp.read_text()) == case.document():
        return folder
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    say(f"simulating {case.name}")
    source = _floor_source(case.floor)
    simulate_sequence(
        folder,
        floor=_cropped(source, case.crop, folder) if case.crop else source,
        floor_mm_per_px=case.floor_mm_per_px,
        path=case.path,
        seconds=case.seconds or None,
        seed=case.seed,
        effects=case.effects,
        commands=list(case.commands) if case.commands else None,
    )
    stamp.write_text(json.dumps(case.document()))
    return folder


def _measure(folder: Path, method: str, model: Path | None, threads: int) -> dict:
    camera = FloorCamera.from_document(json.loads((folder / "camera.json").read_text()))
    run = run_odometry(
        folder / "frames",
        camera,
        OdometryParams(method=method),
        model=model if method == "oenet" else None,
        threads=threads,
    )
    scores = evaluate(run.trajectory, read_tum(folder / "truth.tum"), run.covariance[-1])
    return {
        **scores.document(),
        "flagged": run.flagged,
        "warned": run.warned,
        "pairs_per_s": run.pairs_per_s,
    }


def _train_oenet(model: Path, work: Path, threads: int) -> None:
    """OE-Net trained as `vista odometry train` trains it by default (on the CPU)."""
    from contract.training import config_from
    from services.lib.nn.regression import TrainConfig
    from services.odometry.oenet import train_oenet, training_summary

    folders = [
        _sequence(Case(f"training circuit {s}", "training", path="loop", seconds=0.0, seed=s), work)
        for s in TRAINING_SEEDS
    ]
    config = config_from(TrainConfig, TrainParams(device="cpu"), threads=threads)
    say(f"training OE-Net for {config.epochs} epochs (about an hour on 2 cores)")
    metadata = train_oenet(
        folders,
        model,
        config,
        checkpoint_dir=work / "oenet-checkpoints",
        progress=lambda fraction, message: say(f"  {message}"),
    )
    say(f"OE-Net: {training_summary(metadata)}")


def _fmt(value: float, digits: int = 4) -> str:
    return "–" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def _loop_table(rows: dict[str, dict], thesis_protocol: dict | None) -> str:
    lines = [
        "| method | RMSE δx mm | RMSE δy mm | RMSE δθ ° | final error m | ATE m | drift % "
        "| flagged / warned | pairs/s | heading bias °/frame | NEES | final error within 2σ |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for method, r in rows.items():
        lines.append(
            f"| {method} | {_fmt(r['rmse_dx_mm'])} | {_fmt(r['rmse_dy_mm'])} "
            f"| {_fmt(r['rmse_dtheta_deg'])} | {_fmt(r['final_error_m'])} "
            f"| {_fmt(r['ate_rmse_m'])} | {_fmt(r['drift_percent'], 3)} "
            f"| {r['flagged']} / {r['warned']} "
            f"| {r['pairs_per_s']:.0f} | {r['heading_bias_deg']:.6f} | {_fmt(r['final_nees'], 1)} "
            f"| {'yes' if r['final_within_2_sigma'] else 'no'} |"
        )
    if thesis_protocol:
        lines.append(
            f"| oenet, thesis protocol (its 10 % test pairs) | {_fmt(thesis_protocol['dx_mm'])} "
            f"| {_fmt(thesis_protocol['dy_mm'])} | {_fmt(thesis_protocol['dtheta_deg'])} "
            "| – | – | – | – | – | – | – | – |"
        )
    lines.append(
        "| thesis: OE-Net (its test pairs) | 0.0649 | 0.0603 | 0.51 | 0.0303 | – | 0.106 | – | – | – | – | – |"
    )
    return "\n".join(lines)


def _sweep_table(rows: list[dict], methods: tuple[str, ...]) -> str:
    head = " | ".join(f"{m} drift % (flagged / warned)" for m in methods)
    steps = " | ".join(f"{m} RMSE δx, δy mm / δθ °" for m in methods)
    lines = [
        f"| case | m | {head} | {steps} | vista heading bias °/frame | vista NEES | vista within 2σ |",
        "|---|---|" + "---|" * (2 * len(methods) + 3),
    ]
    for row in rows:
        drift = " | ".join(
            f"{_fmt(row[m]['drift_percent'], 3)} ({row[m]['flagged']} / {row[m]['warned']})"
            for m in methods
        )
        rmse = " | ".join(
            f"{_fmt(row[m]['rmse_dx_mm'])}, {_fmt(row[m]['rmse_dy_mm'])} / "
            f"{_fmt(row[m]['rmse_dtheta_deg'], 3)}"
            for m in methods
        )
        vista = row["vista"]
        lines.append(
            f"| {row['case']} | {row['distance_m']:.2f} | {drift} | {rmse} "
            f"| {vista['heading_bias_deg']:.6f} | {_fmt(vista['final_nees'], 1)} "
            f"| {'yes' if vista['final_within_2_sigma'] else 'no'} |"
        )
    return "\n".join(lines)


def _speed_line(rows: dict[str, dict], fps: float) -> str:
    """vista's speed beside its targets and the peers' from the same run."""
    vista = rows["vista"]["pairs_per_s"]
    others = ", ".join(
        f"{m} {r['pairs_per_s']:.0f} pairs/s ({vista / r['pairs_per_s']:.1f}× slower than vista)"
        for m, r in rows.items()
        if m != "vista"
    )
    return (
        f"Speed: vista {vista:.0f} pairs/s = {vista / fps:.1f}× real time at {fps:.0f} fps "
        f"(target ≥ {TARGETS['vista_pairs_per_s']} pairs/s, ≥ 5× real time, "
        f"≥ {TARGETS['vista_times_the_peer']:.0f}× the peer); same run: {others}"
    )


def _verdict(loop: dict[str, dict], sweep: list[dict], thesis_protocol: dict | None) -> dict:
    vista = loop["vista"]
    floors = [row["vista"]["drift_percent"] for row in sweep if row["group"] == "floor"]
    verdict = {
        "vista: RMSE δx, δy ≤ 0.03 mm and δθ ≤ 0.05° on the circuit": max(
            vista["rmse_dx_mm"], vista["rmse_dy_mm"]
        )
        <= TARGETS["vista_rmse_dxy_mm"]
        and vista["rmse_dtheta_deg"] <= TARGETS["vista_rmse_dtheta_deg"],
        "vista: final error ≤ 0.03 m over the 28.6 m circuit": vista["final_error_m"]
        <= TARGETS["vista_final_error_m"],
        "vista: ≥ 300 pairs/s on this machine's cores (5× real time at 60 fps)": vista[
            "pairs_per_s"
        ]
        >= TARGETS["vista_pairs_per_s"],
    }
    if "phase" in loop:
        times = vista["pairs_per_s"] / loop["phase"]["pairs_per_s"]
        verdict[
            f"vista: ≥ 6× the phase-correlation peer's pairs/s in the same run ({times:.1f}×)"
        ] = times >= TARGETS["vista_times_the_peer"]
    if floors:
        verdict["vista: drift ≤ 0.2 % on every floor, the unseen one included"] = (
            max(floors) <= TARGETS["vista_drift_percent_every_floor"]
        )
    photos = [row["vista"]["drift_percent"] for row in sweep if row["group"] == "photo"]
    if photos:
        verdict[f"vista: drift ≤ 0.2 % on every real photograph (worst {max(photos):.3f} %)"] = (
            max(photos) <= TARGETS["vista_drift_percent_real_photos"]
        )
    for row in sweep:
        if row["group"] == "straight":
            bias = abs(row["vista"]["heading_bias_deg"])
            verdict[f"vista: heading bias < 0.0002° a frame, {row['case']} ({bias:.6f})"] = (
                bias < TARGETS["vista_heading_bias_deg_per_frame"]
            )
    judged = [row["vista"]["final_within_2_sigma"] for row in sweep] + [
        vista["final_within_2_sigma"]
    ]
    share = sum(bool(j) for j in judged) / len(judged)
    verdict[f"vista: final error within 2σ in ≥ 90 % of the cases ({share:.0%})"] = (
        share >= TARGETS["vista_share_within_2_sigma"]
    )
    if "oenet" in loop:
        oenet = loop["oenet"]
        verdict["OE-Net within 2× of the thesis on the circuit (δx, δy ≤ 0.13 mm, δθ ≤ 1°)"] = (
            max(oenet["rmse_dx_mm"], oenet["rmse_dy_mm"]) <= TARGETS["oenet_rmse_dxy_mm"]
            and oenet["rmse_dtheta_deg"] <= TARGETS["oenet_rmse_dtheta_deg"]
        )
    if thesis_protocol:
        verdict["OE-Net within 2× of the thesis by its protocol (test pairs)"] = (
            max(thesis_protocol["dx_mm"], thesis_protocol["dy_mm"]) <= TARGETS["oenet_rmse_dxy_mm"]
            and thesis_protocol["dtheta_deg"] <= TARGETS["oenet_rmse_dtheta_deg"]
        )
    return verdict


def run_odometry_bench(
    out: Path,
    *,
    oenet_model: Path | None,
    work: Path | None = None,
    cases: tuple[Case, ...] = SWEEP,
    loop: Case | None = LOOP,
    threads: int | None = None,
) -> dict:
    """Simulate (or reuse from ``work``) the circuit and the sweep's sequences, run every
    method on each, print the tables and the verdict, write the JSON document.
    ``oenet_model``: an OE-Net to use, trained here first when the file does not exist;
    None leaves OE-Net out."""
    prepare_process()
    threads = threads or available_cores()
    scratch = None
    if work is None:
        scratch = Path(tempfile.mkdtemp(prefix="vista-odometry-bench-"))
        work = scratch
    try:
        methods = tuple(m for m in METHODS if oenet_model is not None or m != "oenet")
        thesis_protocol = None
        if oenet_model is not None:
            if not oenet_model.exists():
                _train_oenet(oenet_model, work, threads)
            from services.lib.nn.onnx_io import read_model

            metrics = read_model(oenet_model).metadata.get("metrics") or {}
            thesis_protocol = metrics.get("test_rmse")
        loop_rows: dict[str, dict] = {}
        if loop is not None:
            folder = _sequence(loop, work)
            for method in methods:
                say(f"{loop.name}: {method}")
                loop_rows[method] = _measure(folder, method, oenet_model, threads)
        sweep_rows = []
        for case in cases:
            folder = _sequence(case, work)
            row = {"case": case.name, "group": case.group}
            for method in methods:
                row[method] = _measure(folder, method, oenet_model, threads)
            row["distance_m"] = row["vista"]["distance_m"]
            say(
                f"{case.name}: "
                + ", ".join(f"{m} drift {_fmt(row[m]['drift_percent'], 3)} %" for m in methods)
            )
            sweep_rows.append(row)
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    verdict = _verdict(loop_rows, sweep_rows, thesis_protocol) if loop_rows else {}
    document = write_document(
        out,
        bench="odometry",
        targets=TARGETS,
        verdict=verdict,
        threads=threads,
        oenet_model=str(oenet_model) if oenet_model else None,
        oenet_thesis_protocol=thesis_protocol,
        loop=loop_rows,
        sweep=sweep_rows,
        cases=[c.document() for c in cases],
    )
    if loop_rows:
        print(f"\n## {LOOP.name} at 60 fps, concrete ({threads} threads)\n")
        print(_loop_table(loop_rows, thesis_protocol))
        print("\n" + _speed_line(loop_rows, FloorCamera.thesis().fps))
    if sweep_rows:
        print("\n## Sweep (each method on the same frames)\n")
        print(_sweep_table(sweep_rows, methods))
    print_verdict(verdict, out)
    return document
