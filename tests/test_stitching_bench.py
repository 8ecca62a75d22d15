"""The stitching benchmark's parts on a small scale (the full run is `vista bench stitching`)."""

from __future__ import annotations

import numpy as np

from services.lib.pointcloud.ply import read_ply
from services.stitching.bench import CASES, _run_pipeline, calibration_bench
from services.stitching.calibration import calibrate
from services.stitching.example import write_example
from services.stitching.files import read_pairs, read_truth, write_handeye
from services.stitching.report import distance_to_truth_mm


def test_both_pipelines_stitch_the_same_example(tmp_path) -> None:
    write_example(tmp_path, component="angle", grid=(120, 185), seed=2)
    write_handeye(tmp_path / "handeye.json", calibrate(*read_pairs(tmp_path / "pairs.json")))
    runs = {w: _run_pipeline(w, tmp_path, tmp_path / f"{w}.ply") for w in ("vista", "open3d")}
    truth = read_truth(tmp_path / "truth.json")
    for which, run in runs.items():
        assert run["input_points"] == runs["vista"]["input_points"] > 30_000
        assert 0 < run["output_points"] < run["input_points"]
        assert run["peak_rss_mb"] >= run["loaded_rss_mb"] > 0 and run["seconds"] > 0
        # Both outputs lie on the simulated part's true surface.
        error = distance_to_truth_mm(truth, read_ply(tmp_path / f"{which}.ply").points)
        assert np.mean(error) < 0.12 and np.percentile(error, 99) < 0.5, which
    # On this coarse grid (0.83 mm spacing) nearest-point distances are set by the spacing:
    # two aligned samplings average about 0.4 spacings apart.
    spacing_mm = 154.0 / 185
    assert runs["vista"]["overlap_pairs"] >= 2
    assert runs["vista"]["overlap"]["mean_mm"] < 0.5 * spacing_mm


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
