"""``vista stitching bench``: the stitching service against its peers, in one run.

(i) Full scale — ten Gocator 3210 snapshots (1288 × 1936, ~2.5 M points each) of a
simulated flat strip: vista's stitch + clean against the same steps written with Open3D's
API (per-scan k-NN normals and statistical outlier removal, transform, merge, voxel
down-sampling, radius outlier filter). Each pipeline runs in its own process on the same
files, so wall time and peak memory are its own; the outputs are measured against the true
surface, and vista's overlap quality (thesis Fig. 6.2) is reported.

(ii) Calibration — median pose error of flange_T_sensor over simulated sessions, and time,
for the thesis's basin hopping, OpenCV's five closed-form methods and vista, over noise
levels and pose counts, with and without a corrupted pair (a mis-detected plate hole).
Basin hopping takes seconds per session, so it runs in the two headline cases only.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.bench import print_verdict, write_document
from contract.bench import say as say_progress
from services.lib.pointcloud.ply import read_ply
from services.lib.pointcloud.transforms import pose_error
from services.stitching.calibration import METHODS, OPENCV_METHODS, calibrate
from services.stitching.calibration_sim import simulate_calibration
from services.stitching.kinds import NoiseModel

TARGETS = {
    "stitch_seconds_max": 60.0,
    "stitch_peak_gb_max": 6.0,
    "speedup_vs_open3d_min": 2.0,
    "overlap_mean_mm_max": 0.11,
    "overlap_p90_mm_max": 0.15,
    "calibration_translation_mm_max": 0.08,
    "calibration_rotation_deg_max": 0.025,
    "corrupted_translation_mm_max": 0.1,
    "corrupted_rotation_deg_max": 0.04,
    "speedup_vs_thesis_min": 100.0,
}
TRUE_ERROR_SAMPLE = 2_000_000
STRAY_MM = 0.5
"""Output points farther than this from the true surface count as strays left behind."""


@dataclass(frozen=True)
class CalibrationCase:
    name: str
    poses: int = 15
    noise_scale: float = 1.0
    corrupt: int = 0
    thesis: bool = False


CASES = (
    CalibrationCase("nominal", thesis=True),
    CalibrationCase("1 corrupted pair", corrupt=1, thesis=True),
    CalibrationCase("half noise", noise_scale=0.5),
    CalibrationCase("double noise", noise_scale=2.0),
    CalibrationCase("8 poses", poses=8),
    CalibrationCase("30 poses", poses=30),
)


def calibration_bench(
    sessions: int, *, thesis_sessions: int, seed: int = 0, say: Callable = say_progress
) -> list[dict]:
    """Per case and method: median/p90 translation and rotation error, median time; for
    corrupted cases, in how many sessions vista named exactly the bad pairs; for vista, a
    paired comparison with the best OpenCV method of the case (same sessions)."""
    rows = []
    for case in CASES:
        methods = [m for m in METHODS if m != "thesis" or case.thesis]
        errors: dict[str, list] = {m: [] for m in methods}
        seconds: dict[str, list] = {m: [] for m in methods}
        named = 0
        noise = _scaled(NoiseModel(), case.noise_scale)
        for session_index in range(sessions):
            rng = np.random.default_rng([seed, session_index, case.poses, case.corrupt])
            session = simulate_calibration(
                poses=case.poses, **noise.model_dump(), corrupt=case.corrupt, rng=rng
            )
            for method in methods:
                if method == "thesis" and session_index >= thesis_sessions:
                    continue
                started = time.perf_counter()
                result = calibrate(
                    session.base_T_flange, session.sensor_T_target, method=method, noise=noise
                )
                seconds[method].append(time.perf_counter() - started)
                errors[method].append(
                    pose_error(result.flange_T_sensor, session.true_flange_T_sensor)
                )
                if method == "vista" and case.corrupt:
                    named += sorted(d.index for d in result.dropped) == list(session.corrupted)
        say(f"calibration, {case.name}: {sessions} sessions × {len(methods)} methods")
        errors_np = {m: np.array(e) for m, e in errors.items()}
        for method in methods:
            e = errors_np[method]
            row = {
                "case": case.name,
                "poses": case.poses,
                "noise_scale": case.noise_scale,
                "corrupted_pairs": case.corrupt,
                "method": method,
                "sessions": len(e),
                "translation_median_mm": float(np.median(e[:, 0])),
                "translation_p90_mm": float(np.percentile(e[:, 0], 90)),
                "rotation_median_deg": float(np.median(e[:, 1])),
                "rotation_p90_deg": float(np.percentile(e[:, 1], 90)),
                "time_median_ms": float(np.median(seconds[method]) * 1000),
            }
            if method == "vista":
                row["paired"] = _paired(errors_np)
                if case.corrupt:
                    row["bad_pair_named"] = named
            rows.append(row)
    return rows


def _scaled(noise: NoiseModel, factor: float) -> NoiseModel:
    """Every σ of ``noise`` times ``factor``: the same robot and sensor, more or less noisy."""
    return NoiseModel(**{name: sigma * factor for name, sigma in noise.model_dump().items()})


def _paired(errors: dict[str, np.ndarray]) -> dict:
    """vista against the OpenCV method with the lowest median, per error, on the same
    sessions: mean of (vista − peer), the share of sessions vista is better, Wilcoxon p."""
    from scipy.stats import wilcoxon

    out = {}
    for column, name in ((0, "translation"), (1, "rotation")):
        peer = min(OPENCV_METHODS, key=lambda m: np.median(errors[m][:, column]))
        difference = errors["vista"][:, column] - errors[peer][:, column]
        out[name] = {
            "peer": peer,
            "mean_difference": float(difference.mean()),
            "vista_better_share": float(np.mean(difference < 0)),
            "wilcoxon_p": float(wilcoxon(difference).pvalue),
        }
    return out


def _run_pipeline(which: str, example: Path, out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    command = [sys.executable, "-m", "services.stitching.bench_worker", which, str(example)]
    done = subprocess.run(
        [*command, str(out)], env=env, capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise RuntimeError(f"{which} pipeline failed:\n{done.stderr[-4000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def full_scale_bench(folder: Path, *, seed: int = 0, say: Callable = say_progress) -> dict:
    from services.lib.pointcloud.scan_sim import GOCATOR_GRID
    from services.stitching.example import write_example
    from services.stitching.files import read_pairs, read_truth, write_handeye
    from services.stitching.report import distance_to_truth_mm

    say("full scale: simulating ten 1288 × 1936 snapshots of a flat strip …")
    started = time.perf_counter()
    example = write_example(folder, component="strip", grid=GOCATOR_GRID, seed=seed)
    say(f"  {example.scans} scans simulated in {time.perf_counter() - started:.0f} s")
    handeye = calibrate(*read_pairs(folder / "pairs.json"))
    write_handeye(folder / "handeye.json", handeye)
    truth = read_truth(folder / "truth.json")
    rng = np.random.default_rng(seed)
    results = {}
    for which in ("vista", "open3d"):
        say(f"  {which}: stitch + clean …")
        out = folder / f"{which}.ply"
        run = _run_pipeline(which, folder, out)
        points = read_ply(out).points
        sample = points[rng.choice(len(points), min(TRUE_ERROR_SAMPLE, len(points)), False)]
        distance = distance_to_truth_mm(truth, sample)
        run["true_error_mean_mm"] = float(distance.mean())
        run["true_error_p90_mm"] = float(np.percentile(distance, 90))
        run["stray_share"] = float(np.mean(distance > STRAY_MM))
        results[which] = run
        say(f"    {run['seconds']:.1f} s, peak {run['peak_rss_mb'] / 1024:.2f} GB")

    vista, peer = results["vista"], results["open3d"]
    overlap, overlap_pairs = vista.pop("overlap"), vista.pop("overlap_pairs")
    return {
        "scans": example.scans,
        "grid": list(GOCATOR_GRID),
        "vista": vista,
        "open3d": peer,
        "speedup": peer["seconds"] / vista["seconds"],
        "peak_memory_ratio": vista["peak_rss_mb"] / peer["peak_rss_mb"],
        "overlap": overlap,
        "overlap_pairs": overlap_pairs,
    }


def _calibration_table(rows: list[dict]) -> str:
    lines = [
        "| case | method | t median mm | t p90 mm | r median ° | r p90 ° | time ms | bad pair named |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        named = "" if "bad_pair_named" not in r else f"{r['bad_pair_named']}/{r['sessions']}"
        lines.append(
            f"| {r['case']} | {r['method']} | {r['translation_median_mm']:.4f} | "
            f"{r['translation_p90_mm']:.4f} | {r['rotation_median_deg']:.4f} | "
            f"{r['rotation_p90_deg']:.4f} | {r['time_median_ms']:.1f} | "
            f"{named} |"
        )
    return "\n".join(lines)


def _full_scale_table(full: dict) -> str:
    lines = [
        "| pipeline | seconds | peak GB | input points | output points | true error mean mm "
        "| p90 mm | strays > 0.5 mm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in ("vista", "open3d"):
        r = full[name]
        lines.append(
            f"| {name} | {r['seconds']:.1f} | {r['peak_rss_mb'] / 1024:.2f} | "
            f"{r['input_points']:,} | {r['output_points']:,} | {r['true_error_mean_mm']:.4f} | "
            f"{r['true_error_p90_mm']:.4f} | {r['stray_share']:.4%} |"
        )
    o = full["overlap"]
    lines.append(
        f"\nvista {full['speedup']:.1f}× faster, peak memory {full['peak_memory_ratio']:.2f}× "
        f"Open3D's. Overlap ({full['overlap_pairs']} pairs): mean {o['mean_mm']:.4f} mm, std "
        f"{o['std_mm']:.4f}, p90 {o['p90_mm']:.4f}, max {o['max_mm']:.3f}"
    )
    return "\n".join(lines)


def _verdict(full: dict | None, rows: list[dict]) -> dict[str, bool]:
    def row(case: str, method: str) -> dict:
        return next(r for r in rows if r["case"] == case and r["method"] == method)

    nominal, corrupted = row("nominal", "vista"), row("1 corrupted pair", "vista")
    opencv = [r for r in rows if r["case"] == "nominal" and r["method"] not in ("vista", "thesis")]
    best_t = min(r["translation_median_mm"] for r in opencv)
    best_r = min(r["rotation_median_deg"] for r in opencv)
    t, r = nominal["translation_median_mm"], nominal["rotation_median_deg"]
    verdict = {
        "calibration_no_worse_than_best_opencv": t <= best_t and r <= best_r,
        "calibration_within_limits": t <= TARGETS["calibration_translation_mm_max"]
        and r <= TARGETS["calibration_rotation_deg_max"],
        "corrupted_within_limits": corrupted["translation_median_mm"]
        <= TARGETS["corrupted_translation_mm_max"]
        and corrupted["rotation_median_deg"] <= TARGETS["corrupted_rotation_deg_max"],
        "bad_pair_always_named": corrupted["bad_pair_named"] == corrupted["sessions"],
        "faster_than_thesis": row("nominal", "thesis")["time_median_ms"]
        >= TARGETS["speedup_vs_thesis_min"] * nominal["time_median_ms"],
    }
    if full is not None:
        v = full["vista"]
        verdict |= {
            "stitch_time": v["seconds"] <= TARGETS["stitch_seconds_max"],
            "stitch_memory": v["peak_rss_mb"] / 1024 <= TARGETS["stitch_peak_gb_max"],
            "stitch_speedup": full["speedup"] >= TARGETS["speedup_vs_open3d_min"],
            "overlap_mean": full["overlap"]["mean_mm"] <= TARGETS["overlap_mean_mm_max"],
            "overlap_p90": full["overlap"]["p90_mm"] <= TARGETS["overlap_p90_mm_max"],
        }
    return verdict


def run_stitching_bench(
    out: Path, *, sessions: int, thesis_sessions: int, full_scale: bool, seed: int = 0
) -> dict:
    full = None
    if full_scale:
        with tempfile.TemporaryDirectory(prefix="vista-bench-stitching-") as folder:
            full = full_scale_bench(Path(folder), seed=seed)
    rows = calibration_bench(sessions, thesis_sessions=thesis_sessions, seed=seed)
    verdict = _verdict(full, rows)
    document = write_document(
        out,
        bench="stitching",
        targets=TARGETS,
        full_scale=full,
        calibration=rows,
        verdict=verdict,
    )
    if full is not None:
        print("\n## Full scale: stitch + clean, vista vs Open3D\n")
        print(_full_scale_table(full))
    print(
        f"\n## Calibration: flange_T_sensor error over {sessions} sessions per case "
        f"(basin hopping: the first {min(thesis_sessions, sessions)})\n"
    )
    print(_calibration_table(rows))
    print("\nvista against the best OpenCV method on the same sessions:\n")
    for r in (r for r in rows if r["method"] == "vista"):
        t, q = r["paired"]["translation"], r["paired"]["rotation"]
        print(
            f"- {r['case']}: translation vs {t['peer']} {t['mean_difference']:+.4f} mm, "
            f"better in {t['vista_better_share']:.0%} (Wilcoxon p {t['wilcoxon_p']:.3g}); "
            f"rotation vs {q['peer']} {q['mean_difference']:+.5f}°, better in "
            f"{q['vista_better_share']:.0%} (p {q['wilcoxon_p']:.3g})"
        )
    print_verdict(verdict, out)
    return document
