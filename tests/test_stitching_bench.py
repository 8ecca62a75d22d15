"""The stitching benchmark's parts on a small scale (the full run is `vista bench stitching`)."""

from __future__ import annotations

import numpy as np

from services.stitching.bench import CASES, _run_pipeline, calibration_bench
from services.stitching.calibration import calibrate
from services.stitching.example import write_example
from services.stitching.files import read_pairs, write_handeye


def test_both_pipelines_stitch_the_same_example(tmp_path) -> None:
    write_example(tmp_path, component="angle", grid=(120, 185), seed=2)
    write_handeye(tmp_path / "handeye.json", calibrate(*read_pairs(tmp_path / "pairs.json")))
    runs = {w: _run_pipeline(w, tmp_path, tmp_path / f"{w}.ply") for w in ("vista", "open3d")}
    for run in runs.values():
        assert run["input_points"] == runs["vista"]["input_points"] > 30_000
        assert 0 < run["output_points"] < run["input_points"]
        assert run["peak_rss_mb"] >= run["loaded_rss_mb"] > 0 and run["seconds"] > 0


def test_calibration_bench_rows() -> None:
    rows = calibration_bench(4, thesis_sessions=1, say=lambda message: None)
    thesis = [r for r in rows if r["method"] == "thesis"]
    assert len(thesis) == sum(case.thesis for case in CASES)
    assert all(r["sessions"] == 1 for r in thesis)
    vista = {r["case"]: r for r in rows if r["method"] == "vista"}
    assert vista["1 corrupted pair"]["bad_pair_named"] == 4
    assert vista["1 corrupted pair"]["translation_median_mm"] < 0.15
    paired = vista["nominal"]["paired"]["rotation"]
    assert paired["peer"] in ("tsai", "park", "horaud", "andreff", "daniilidis")
    assert 0.0 <= paired["vista_better_share"] <= 1.0 and np.isfinite(paired["mean_difference"])
