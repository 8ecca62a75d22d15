"""The Siamese tracker's search: the local search scores fewer candidates where the motion
model is right and the answer sure, and falls back to the full grid where it is not — on a
synthetic similarity, and on a tracker with a small hand-made encoder (no training)."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from services.tracking.siamese import (
    SURE_SIMILARITY,
    candidate_grid,
    search_grid,
    start_cells,
)


def _peak(
    centre_m: tuple[float, float], height: float
) -> tuple[Callable[[np.ndarray], np.ndarray], list[int]]:
    """A similarity of ``height`` at ``centre_m`` (dx, dy), falling off as a Gaussian
    (σ 0.7 m), best at no turn; and the log of every call's batch."""
    calls: list[int] = []

    def similarity(poses: np.ndarray) -> np.ndarray:
        calls.append(poses.shape[0] * poses.shape[1])
        distance = np.hypot(poses[..., 0] - centre_m[0], poses[..., 1] - centre_m[1])
        return height * np.exp(-0.5 * (distance / 0.7) ** 2) - 0.01 * np.abs(poses[..., 2])

    return similarity, calls


def _full_answer(similarity: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    grid = candidate_grid()
    return grid.reshape(-1, 3)[int(similarity(grid).argmax())]


def test_a_sure_answer_near_the_prediction_scores_27_candidates_in_one_call() -> None:
    similarity, calls = _peak((0.0, 0.0), 0.95)
    found = search_grid(similarity, start_cells(0.5), SURE_SIMILARITY)
    assert calls == [27] and found.candidates == 27 and not found.full
    np.testing.assert_array_equal(found.pose, [0.0, 0.0, 0.0])
    assert found.similarity == pytest.approx(0.95)


def test_the_local_search_climbs_to_a_sure_answer_away_from_the_prediction() -> None:
    similarity, calls = _peak((1.0, -1.0), 0.95)
    found = search_grid(similarity, start_cells(0.5), SURE_SIMILARITY)
    np.testing.assert_array_equal(found.pose, _full_answer(similarity))
    assert calls[0] == 27 and len(calls) > 1  # the start, then the cells towards the peak
    assert found.candidates < 147 and not found.full


def test_an_unsure_best_falls_back_to_the_full_grid() -> None:
    # a weak peak at the grid's edge: the climb finds it, but below SURE_SIMILARITY the rest
    # of the grid is scored as well, and the answer is the full search's
    similarity, calls = _peak((1.5, 1.5), 0.6)
    found = search_grid(similarity, start_cells(0.5), SURE_SIMILARITY)
    assert found.full and found.candidates == 147 and sum(calls) == 147
    np.testing.assert_array_equal(found.pose, _full_answer(similarity))
    # the full search scores everything in one call
    similarity, calls = _peak((0.0, 0.0), 0.95)
    found = search_grid(similarity, np.ones((7, 7), dtype=bool), SURE_SIMILARITY)
    assert calls == [147] and found.full


SIZE = np.array([4.0, 1.8, 1.5])


def _shape_encoder(path: Path) -> Path:
    """An ONNX 'encoder' of the Siamese architecture that needs no training: a box's points →
    (4 × mean x, 4 × mean y, mean distance from the mean along x, y, z, 10 × the mean of
    x y about the mean; metres), so a candidate centred and turned on a shape like the
    model's is similar to it (cosine ≈ 1), one 0.5 m off or 5° turned less, and a shape of
    another spread is not."""
    import torch

    from services.lib.nn.onnx_io import export_onnx
    from services.tracking.siamese import ARCHITECTURE, POINTS

    class Shape(torch.nn.Module):
        def forward(self, points: torch.Tensor) -> torch.Tensor:
            mean = points.mean(dim=2)
            centred = points - mean[:, :, None]
            spread = centred.abs().mean(dim=2)
            skew = (centred[:, 0] * centred[:, 1]).mean(dim=1, keepdim=True)
            return torch.cat([4 * mean[:, :2], spread, 10 * skew], dim=1)

    example = np.random.default_rng(0).normal(size=(2, 3, POINTS)).astype(np.float32)
    export_onnx(Shape(), example, path, {"architecture": ARCHITECTURE}, input_name="points", output_name="latent")  # fmt: skip
    return path


def _scan(centre_x: float, rng: np.random.Generator, length_m: float = SIZE[0]) -> np.ndarray:
    """(N, 4) a car-sized block of returns centred at (centre_x, 0, 0) (``length_m`` long)
    on a ground plane under it."""
    half = np.array([length_m, SIZE[1], SIZE[2]]) / 2
    body = rng.uniform(-half, half, size=(3000, 3)) + [centre_x, 0.0, 0.0]
    ground = np.column_stack(
        [
            rng.uniform(centre_x - 8, centre_x + 8, 2000),
            rng.uniform(-6, 6, 2000),
            np.full(2000, -0.75),
        ]
    )
    points = np.concatenate([body, ground])
    return np.column_stack([points, np.zeros(len(points))]).astype(np.float32)


def test_the_tracker_searches_locally_once_settled_and_fully_when_the_target_changes(
    tmp_path: Path,
) -> None:
    from services.tracking.siamese import SiameseTracker

    model = _shape_encoder(tmp_path / "shape.onnx")
    rng = np.random.default_rng(1)
    speed_m = 1.0
    local, full = (SiameseTracker(model, seed=0, search=s) for s in ("local", "full"))
    for tracker in (local, full):
        tracker.start(_scan(10.0, rng), np.array([10.0, 0.0, 0.0, *SIZE, 0.0]))
    scored = {"local": [], "full": []}
    errors_m = []
    for frame in range(1, 13):
        # the last frame's target is a thin slab: nothing there looks like the model
        scan = _scan(10.0 + speed_m * frame, rng, length_m=0.3 if frame == 12 else SIZE[0])
        for name, tracker in (("local", local), ("full", full)):
            before = tracker.candidates_scored
            step = tracker.step(scan, None)
            scored[name].append(tracker.candidates_scored - before)
            if name == "local" and frame < 12:
                errors_m.append(abs(step.box[0] - (10.0 + speed_m * frame)))
    assert scored["full"] == [147] * 12
    # the first frames search the full grid (the motion model has no velocity yet) …
    assert scored["local"][0] == 147
    # … then, the answers sure and near their predictions, mostly a few dozen a frame
    assert np.median(scored["local"][1:11]) <= 42
    assert sum(scored["local"][1:11]) < 0.5 * 147 * 10, scored["local"]
    assert max(errors_m) < 1.0  # on the 4 m target all along (the toy encoder is coarse)
    # the slab: no candidate is sure, the whole grid is scored
    assert scored["local"][11] == 147


def test_one_cut_from_the_scan_holds_the_search_and_every_candidates_box() -> None:
    """The tracker cuts a frame's points from the scan once (``REACH_M``): its search's crop
    and ``in_box`` of any candidate, at any heading, are what they are on the whole scan."""
    from services.lib.boxes import YAW, from_box_frame, wrap
    from services.tracking.siamese import MARGIN_M, REACH_M, candidate_poses
    from services.tracking.tracker import crop, in_box, nearby

    rng = np.random.default_rng(2)
    scan = np.column_stack(
        [rng.uniform(-12, 12, (200_000, 2)), rng.uniform(-1.2, 1.2, 200_000), np.zeros(200_000)]
    )
    for heading in np.radians([0.0, 30.0, 45.0, 100.0]):
        predicted = np.array([0.3, -0.2, 0.0, 5.2, 2.1, 1.6, heading])
        around = nearby(scan, predicted, REACH_M)
        assert len(around) < len(scan) / 4
        np.testing.assert_array_equal(
            crop(around, predicted, MARGIN_M), crop(scan, predicted, MARGIN_M)
        )
        for dx, dy, turn in candidate_poses():
            box = predicted.copy()
            box[:3] = from_box_frame(np.array([[dx, dy, 0.0]]), predicted)[0]
            box[YAW] = wrap(heading + turn)
            np.testing.assert_array_equal(in_box(around, box), in_box(scan, box))


def test_the_bench_compares_the_searches_over_seeds_by_their_means(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The bench's local-against-full comparison on a small drive: each search re-run with
    each seed on the reference resets, then per reset each search's mean, lowest and
    highest score and the local mean less the full one."""
    from services.tracking import bench
    from services.tracking.detect_geometric import GeometricDetector
    from services.tracking.siamese import SiameseTracker
    from tests.lidarfiles import small_drive

    monkeypatch.setattr(bench, "SEARCH_SEEDS", 2)
    model = _shape_encoder(tmp_path / "shape.onnx")
    work = bench.simulated_workload([small_drive(tmp_path / "drive")], min_frames=10)
    # The bench's own seed-0 local sweep, in another order: taken by reset, not run again.
    tracker = partial(SiameseTracker, model, threads=2)
    first = bench.sweep(work, tracker, GeometricDetector(), bench.FULL_SEARCH_POLICIES[::-1])
    runs = bench._search_runs(work, model, GeometricDetector(), bench.FULL_SEARCH_POLICIES, first)
    assert {search: len(seeds) for search, seeds in runs.items()} == {"local": 2, "full": 2}
    assert all(a is b for a, b in zip(runs["local"][0], first[::-1], strict=True))
    for seeds in runs.values():
        for rows in seeds:
            assert [r["reset"] for r in rows] == list(bench.FULL_SEARCH_POLICIES)
    comparison = bench._search_comparison(runs)
    assert [r["reset"] for r in comparison] == list(bench.FULL_SEARCH_POLICIES)
    for k, row in enumerate(comparison):
        for search, seeds in runs.items():
            values = [rows[k]["success"] for rows in seeds]
            stats = row[f"{search}_success"]
            assert stats["min"] == min(values) and stats["max"] == max(values)
            assert stats["mean"] == pytest.approx(np.mean(values), abs=0.01)
        assert row["success_difference"] == pytest.approx(
            row["local_success"]["mean"] - row["full_success"]["mean"], abs=0.01
        )
