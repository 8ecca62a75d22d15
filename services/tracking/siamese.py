"""The thesis's tracker branch: SC3D's Siamese shape matching (Giancola, Zarzar and Ghanem,
"Leveraging Shape Completion for 3D Siamese Tracking", CVPR 2019), trained here.

A PointNet encodes the points of a box, in the box's frame, into a latent vector. The
target's model is the points of the first frame's box and of the previous frame's answer
(SC3D's model: the first and the previous); the candidates are 147 boxes around the
motion model's prediction (7 × 7 offsets 0.5 m apart, three headings 5° apart), each
searched candidate's points encoded, and the candidate whose latent is closest to the
model's by cosine similarity is the answer. Training regresses the cosine
similarity of model and candidate to a Gaussian of the candidate's offset from the truth,
with SC3D's shape-completion regulariser: a decoder rebuilds the target's complete shape
(all of its tracklet's points) from the model's latent (Chamfer distance).

The confidence is the best candidate's similarity, 0–1.

**The search.** SC3D scores all 147 candidates every frame (``search="full"``, kept as the
reference). vista's default (``search="local"``) scores fewer where the motion model is
good: once ``SETTLED_FRAMES`` answers in a row were sure (similarity ≥ ``SURE_SIMILARITY``)
and within ``SETTLED_REACH_M`` of their prediction, a frame starts with the 3 × 3 offsets
around the prediction (27 candidates) and grows the scored cells towards the best one
until the best has all its neighbours scored (a maximum of the similarity over the grid);
when that best is not sure, the rest of the grid is scored as the full search would. A
frame after a reset, a lost target or an unsure answer searches the full grid. The model's
latent is encoded when the model changes, at most once a frame, not after every step.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from services.lib.boxes import YAW, from_box_frame, wrap
from services.lib.nn.fit import Progress
from services.tracking.kinds import (
    SIAMESE_BATCH,
    SIAMESE_EPOCHS,
    SIAMESE_LEARNING_RATE,
    TrainParams,
)
from services.tracking.sequence import open_sequence, tracklets
from services.tracking.tracker import (
    IN_BOX_MARGIN_M,
    MotionModel,
    TrackStep,
    crop,
    in_box,
    nearby,
)

ARCHITECTURE = "sc3d-pointnet"
POINTS = 256
"""Points a box is sampled to (SC3D: 2 048; 256 keep 147 candidates a frame fast on a CPU)."""
COMPLETE_POINTS = 512
OFFSETS_M = np.arange(-1.5, 1.51, 0.5)
TURNS_RAD = np.radians([-5.0, 0.0, 5.0])
SIGMA_M, SIGMA_RAD = 0.5, np.radians(10.0)
MARGIN_M = 2.0
"""Points kept around a box: the widest candidate offset (1.5 m) and a turn's reach."""
SEARCH_POINTS = 1200
"""The search draws its candidates' points from at most this many around the prediction."""
START_REACH_M = 0.5
"""The local search starts with the offsets within this of the prediction (3 × 3 cells)."""
SURE_SIMILARITY = 0.8
"""A best candidate this similar is sure: training asks about 0.8 of a candidate 0.33 m
from the truth, and the grid's nearest candidate is at most 0.35 m from it."""
SETTLED_FRAMES = 1
SETTLED_REACH_M = 1.0
"""``SETTLED_FRAMES`` answers in a row sure and within this of their prediction (the motion
model's error small), and the next frame's search is local. On the real drive's short
tracklets (17–19 frames) two answers within 0.5 m searched 64 candidates a frame, one
within 1 m 48, with the same Success and Precision."""
REACH_M = max(MARGIN_M, float(np.hypot(OFFSETS_M.max(), OFFSETS_M.max())) + IN_BOX_MARGIN_M)
"""A frame's points are cut from the scan once, this far around the prediction: enough
for the search's crop and for ``in_box`` of any candidate."""
Search = Literal["local", "full"]


def sample_points(local: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, 3): ``local`` points drawn (repeated when fewer; zeros when none)."""
    if not len(local):
        return np.zeros((count, 3), dtype=np.float32)
    pick = rng.choice(len(local), count, replace=len(local) < count)
    return local[pick].astype(np.float32)


def candidate_grid() -> np.ndarray:
    """(7, 7, 3, 3) the search's candidates by cell (dx, dy) and turn: their offsets (dx, dy
    in the box's frame, metres; dθ radians)."""
    return np.stack(np.meshgrid(OFFSETS_M, OFFSETS_M, TURNS_RAD, indexing="ij"), axis=-1)


def candidate_poses() -> np.ndarray:
    """(147, 3) offsets (dx, dy in the box's frame, metres; dθ radians) of the search."""
    return candidate_grid().reshape(-1, 3)


def start_cells(reach_m: float) -> np.ndarray:
    """(7, 7) bool: the grid's cells whose offsets are both within ``reach_m``."""
    near = np.abs(OFFSETS_M) <= reach_m + 1e-9
    return near[:, None] & near[None, :]


def cells_around(cell: tuple[int, int], scored: np.ndarray) -> np.ndarray:
    """(7, 7) bool: the cells next to ``cell`` (its eight neighbours) not yet ``scored``."""
    rows, columns = np.ogrid[: scored.shape[0], : scored.shape[1]]
    return (np.abs(rows - cell[0]) <= 1) & (np.abs(columns - cell[1]) <= 1) & ~scored


def points_in_candidates(
    local: np.ndarray, size: np.ndarray, poses: np.ndarray, count: int, rng: np.random.Generator
) -> np.ndarray:
    """(K, count, 3): each candidate's points in its own frame, drawn to ``count``, from
    ``local`` (M, 3) points in a reference box's frame; candidates are ``poses`` (K, 3)
    relative to that box, all of ``size`` (l, w, h)."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    dx = local[None, :, 0] - poses[:, 0:1]
    dy = local[None, :, 1] - poses[:, 1:2]
    x, y = c * dx + s * dy, -s * dx + c * dy
    z = np.broadcast_to(local[None, :, 2], x.shape)
    half = size / 2
    within = (np.abs(x) <= half[0]) & (np.abs(y) <= half[1]) & (np.abs(z) <= half[2])
    # draw ``count`` of each candidate's points: random keys, the points outside last; the
    # ``count`` smallest keys (a partition, not a sort), in key order, repeated when short
    keys = np.where(within, rng.uniform(size=within.shape), 2.0)
    if keys.shape[1] > count:
        smallest = np.argpartition(keys, count - 1, axis=1)[:, :count]
    else:
        smallest = np.broadcast_to(np.arange(keys.shape[1]), keys.shape)
    order = np.take_along_axis(
        smallest, np.argsort(np.take_along_axis(keys, smallest, axis=1), axis=1), axis=1
    )
    inside_count = np.minimum(within.sum(axis=1), order.shape[1])
    slots = np.arange(count)[None, :] % np.maximum(inside_count, 1)[:, None]
    chosen = np.take_along_axis(order, slots, axis=1)
    out = np.stack([np.take_along_axis(v, chosen, axis=1) for v in (x, y, z)], axis=-1)
    return np.where(inside_count[:, None, None] > 0, out, 0.0).astype(np.float32)


SETTINGS = TrainParams.model_fields


@dataclass(frozen=True)
class SiameseTrainConfig:
    epochs: int = SIAMESE_EPOCHS
    batch: int = SIAMESE_BATCH
    learning_rate: float = SIAMESE_LEARNING_RATE
    seed: int = SETTINGS["seed"].default
    threads: int = 2
    device: str = SETTINGS["device"].default
    samples_per_epoch: int = SETTINGS["samples"].default
    completion_weight: float = 1.0
    val_fraction: float = 0.1


@dataclass(frozen=True)
class TrackletData:
    """A tracklet's points around each true box (its frame), and its complete shape."""

    crops: list[np.ndarray]
    """Per frame (M, 3) float32 points within ``MARGIN_M`` of the true box, in its frame."""
    size: np.ndarray
    complete: np.ndarray
    group: str


def tracklet_data(folders: list[Path], progress: Progress | None = None) -> list[TrackletData]:
    """Every car tracklet of the labelled sequences in ``folders`` with at least two frames
    whose true box holds points."""
    say = progress or (lambda fraction, message: None)
    out = []
    for number, folder in enumerate(folders):
        sequence = open_sequence(Path(folder))
        if sequence.labels is None:
            raise ValueError(
                f"{folder}: a sequence without labels (label_02.txt): nothing to learn from"
            )
        found = tracklets(sequence, ("Car",), min_frames=2)
        needed = sorted({f for t in found for f in t.frames})
        by_frame: dict[int, np.ndarray] = {f: sequence.points(f)[:, :3] for f in needed}
        for tracklet in found:
            crops = [
                crop(by_frame[f], box, MARGIN_M, floor_m=0.2).astype(np.float32)
                for f, box in zip(tracklet.frames, tracklet.boxes, strict=True)
            ]
            half = tracklet.boxes[0][3:6] / 2
            inner = [c[(np.abs(c) <= half).all(axis=1)] for c in crops]
            if sum(len(c) >= 2 for c in inner) < 2:
                continue
            complete = np.concatenate(inner)
            complete = complete[
                np.random.default_rng(0).choice(
                    len(complete), min(len(complete), 4096), replace=False
                )
            ]
            out.append(TrackletData(crops, tracklet.boxes[0][3:6].copy(), complete, str(folder)))
        say((number + 1) / len(folders), f"{folder}: {len(found)} car tracklets")
    return out


def _inner(data: TrackletData, frame: int) -> np.ndarray:
    points = data.crops[frame]
    return points[(np.abs(points) <= data.size / 2).all(axis=1)]


def training_sample(data: TrackletData, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(model (3, N), candidate (3, N), complete (3, M), score) for a random frame of a
    tracklet: the model of its first and previous frames, a candidate box offset from the
    truth (half close, half as far as the search reaches)."""
    usable = [t for t in range(1, len(data.crops)) if len(_inner(data, t)) >= 2]
    frame = int(rng.choice(usable))
    model = np.concatenate([_inner(data, 0), _inner(data, frame - 1)])
    if rng.uniform() < 0.5:
        offset = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), rng.normal(0, np.radians(4))])
    else:
        offset = np.array(
            [
                rng.uniform(-1.7, 1.7),
                rng.uniform(-1.7, 1.7),
                rng.uniform(-np.radians(12), np.radians(12)),
            ]
        )
    candidate = points_in_candidates(data.crops[frame], data.size, offset[None], POINTS, rng)[0]
    score = np.exp(
        -0.5 * (np.hypot(offset[0], offset[1]) / SIGMA_M) ** 2 - 0.5 * (offset[2] / SIGMA_RAD) ** 2
    )
    return (
        sample_points(model, POINTS, rng).T,
        candidate.T,
        sample_points(data.complete, COMPLETE_POINTS, rng).T,
        np.float32(score),
    )


def chamfer(a, b):  # noqa: ANN001, ANN201 - torch tensors (B, 3, N), (B, 3, M)
    """Mean squared distance of each point to the other set's nearest, both ways (m²)."""
    import torch

    distance = torch.cdist(a.transpose(1, 2), b.transpose(1, 2)) ** 2
    return distance.min(dim=2).values.mean() + distance.min(dim=1).values.mean()


def train_siamese(
    folders: list[Path],
    out: Path,
    config: SiameseTrainConfig,
    *,
    licence: str | None = None,
    checkpoint_dir: Path | None = None,
    progress: Progress | None = None,
    sources: list[str] | None = None,
) -> dict:
    """Train the encoder (and its shape decoder) on the car tracklets of ``folders``; export
    the encoder to ``out`` (ONNX with its metadata) and return the metadata. ``licence`` is
    the training data's, as the metadata should say it."""
    import torch

    from services.lib.nn.fit import fit
    from services.lib.nn.onnx_io import export_onnx
    from services.tracking.datasets import split_groups
    from services.tracking.nets import PointEncoder, ShapeDecoder

    say = progress or (lambda fraction, message: None)
    data = tracklet_data(folders, lambda f, m: say(0.05 * f, m))
    if len(data) < 2:
        raise ValueError(
            f"{len(data)} usable car tracklet(s) in {', '.join(map(str, folders))}: training needs at least 2"
        )
    train_tracklets, val_tracklets = split_groups(
        data, [d.group for d in data], config.val_fraction, config.seed, block=4
    )
    torch.manual_seed(config.seed)
    encoder, decoder = PointEncoder(), ShapeDecoder(points=COMPLETE_POINTS)

    def batch(index: np.ndarray, rng: np.random.Generator, device) -> tuple:  # noqa: ANN001 - a torch device
        chosen = train_tracklets[rng.integers(0, len(train_tracklets), len(index))]
        samples = [training_sample(data[i], rng) for i in chosen]
        return tuple(
            torch.from_numpy(np.stack([s[k] for s in samples])).to(device) for k in range(4)
        )

    def step(batch: tuple) -> tuple:
        model, candidate, complete, score = batch
        z_model, z_candidate = encoder(model), encoder(candidate)
        similarity = torch.nn.functional.cosine_similarity(z_model, z_candidate)
        match = torch.nn.functional.mse_loss(similarity, score)
        completion = chamfer(decoder(z_model), complete)
        return match + config.completion_weight * completion, {
            "match": float(match.detach()),
            "completion": float(completion.detach()),
        }

    rng = np.random.default_rng(config.seed + 7)
    fixed = [training_sample(data[int(rng.choice(val_tracklets))], rng) for _ in range(512)]
    val_batch = tuple(torch.from_numpy(np.stack([s[k] for s in fixed])) for k in range(4))

    def validate() -> float:
        model, candidate, _, score = val_batch
        similarity = torch.nn.functional.cosine_similarity(encoder(model), encoder(candidate))
        return float(torch.nn.functional.mse_loss(similarity, score))

    run = hashlib.sha256(
        json.dumps(
            {
                "config": {
                    k: v
                    for k, v in asdict(config).items()
                    if k not in ("threads", "device", "epochs")
                },
                "data": sources or [str(f) for f in folders],
                "tracklets": len(data),
            },
            sort_keys=True,
        ).encode()
    ).hexdigest()
    result = fit(
        {"encoder": encoder, "decoder": decoder}, step, validate, np.arange(config.samples_per_epoch), batch, config,
        run=run, checkpoint_dir=checkpoint_dir, progress=lambda f, m: say(0.05 + 0.93 * f, m), channels_last=False,
    )  # fmt: skip
    metadata = {
        "architecture": ARCHITECTURE,
        "input": {
            "name": "points",
            "points": POINTS,
            "layout": "(B, 3, N) x y z in the box's frame, metres",
        },
        "search": {"offsets_m": OFFSETS_M.tolist(), "turns_deg": np.degrees(TURNS_RAD).tolist()},
        "parameters": sum(p.numel() for p in encoder.parameters()),
        "training": {
            "data": sources or [str(f) for f in folders],
            "tracklets": {"train": len(train_tracklets), "val": len(val_tracklets)},
            "epochs": config.epochs,
            "best_epoch": result.best_epoch,
            "validation_similarity_mse": round(result.best_score, 5),
            "seconds": round(result.seconds, 1),
            "history": result.history,
            "licence": licence,
            "command": "vista tracking train --network siamese",
        },
    }
    export_onnx(
        encoder.eval(),
        np.zeros((2, 3, POINTS), np.float32),
        out,
        metadata,
        input_name="points",
        output_name="latent",
    )
    say(1.0, f"wrote {out.name}")
    return metadata


@dataclass(frozen=True)
class SearchResult:
    """A frame's search: the best candidate and what it took to find it."""

    pose: np.ndarray
    """(3,) its offset from the prediction (dx, dy in the box's frame, metres; dθ radians)."""
    similarity: float
    """Its cosine similarity to the model (−1 when no candidate held points)."""
    candidates: int
    """Candidates scored."""
    full: bool
    """The whole grid was scored."""


def search_grid(
    similarity_of: Callable[[np.ndarray], np.ndarray], start: np.ndarray, sure_similarity: float
) -> SearchResult:
    """The best candidate of the grid, scoring from the ``start`` cells (7, 7) outwards:
    while the best scored cell has neighbours not scored, score them; when the best found
    is below ``sure_similarity``, score every cell left. ``similarity_of`` takes (C, 3, 3)
    poses (cells × turns) and answers their (C, 3) similarities, one batch a call. Ties go
    to the first candidate in ``candidate_poses``' order, as a full search's argmax."""
    grid = candidate_grid()
    similarity = np.full(grid.shape[:3], -np.inf)
    scored = np.zeros(grid.shape[:2], dtype=bool)
    todo = start.copy()
    while todo.any():
        similarity[todo] = similarity_of(grid[todo])
        scored |= todo
        cell = np.unravel_index(int(similarity.argmax()), similarity.shape)[:2]
        todo = cells_around(cell, scored)
        if not todo.any() and similarity.max() < sure_similarity:
            todo = ~scored
    best = np.unravel_index(int(similarity.argmax()), similarity.shape)
    return SearchResult(
        grid[best], float(similarity[best]), int(scored.sum()) * grid.shape[2], bool(scored.all())
    )


class SiameseTracker:
    """SC3D's tracker on an ONNX encoder of ``ARCHITECTURE``; ``search`` "local" (vista's,
    the default) or "full" (SC3D's: every candidate every frame, the reference it is
    measured against) — see the module's note."""

    name = "siamese"
    sigma_m = 1.0
    """Its answer is one of candidates 0.5 m apart, and its similarity stays high as it
    drifts onto the target's surroundings: it is no surer of a box than this."""

    def __init__(
        self, model: Path, *, threads: int = 1, seed: int = 0, search: Search = "local"
    ) -> None:
        from services.lib.nn.onnx_io import read_model, session

        found = read_model(Path(model))
        if found.metadata.get("architecture") != ARCHITECTURE:
            raise ValueError(
                f"{model}: a {found.metadata.get('architecture')!r} model, not the Siamese tracker's "
                f"encoder ({ARCHITECTURE}); build one with `vista tracking train --network siamese`"
            )
        if search not in ("local", "full"):
            raise ValueError(f"search {search!r}: use 'local' or 'full'")
        self.session = session(Path(model), threads=threads)
        self.search = search
        self.rng = np.random.default_rng(seed)
        self.candidates_scored = 0
        """Candidates encoded over all steps so far: what the local search saves."""

    def _encode(self, points: np.ndarray) -> np.ndarray:
        """(K, latent) unit vectors of (K, N, 3) point sets."""
        (latent,) = self.session.run(
            None, {"points": np.ascontiguousarray(points.transpose(0, 2, 1))}
        )
        return latent / np.maximum(np.linalg.norm(latent, axis=1, keepdims=True), 1e-9)

    @property
    def latent(self) -> np.ndarray:
        """The model's latent, encoded on first use after the model changed."""
        if self._latent is None:
            model = np.concatenate([self.first, self.previous])
            self._latent = self._encode(sample_points(model, POINTS, self.rng)[None])[0]
        return self._latent

    def _remember(self, target: np.ndarray) -> None:
        """The target's points in this frame's answer become the model's previous."""
        if len(target):
            self.previous, self._latent = target, None

    def _similarity(self, local: np.ndarray, size: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """(C, T) cosine similarity to the model of the candidates ``poses`` (C, T, 3) (−1
        for one without points), all encoded in one ONNX call."""
        flat = poses.reshape(-1, 3)
        sets = points_in_candidates(local, size, flat, POINTS, self.rng)
        similarity = self._encode(sets) @ self.latent
        empty = ~sets.any(axis=(1, 2))
        return np.where(empty, -1.0, similarity).reshape(poses.shape[:-1])

    def start(self, points: np.ndarray, box: np.ndarray) -> None:
        self.box = np.asarray(box, dtype=np.float64).copy()
        self.motion = MotionModel(self.box)
        self.first = in_box(points, self.box)
        self.previous, self._latent = self.first, None
        self.settled = 0
        """Answers in a row sure and near their prediction (see ``SETTLED_FRAMES``)."""

    def step(self, points: np.ndarray, prev_T_cur: np.ndarray | None) -> TrackStep:
        predicted = self.motion.advance(prev_T_cur)
        around = nearby(points, predicted, REACH_M)
        local = crop(around, predicted, MARGIN_M)
        if len(local) > SEARCH_POINTS:
            local = local[self.rng.choice(len(local), SEARCH_POINTS, replace=False)]
        box, confidence = predicted.copy(), 0.0
        if len(local):
            local_search = self.search == "local" and self.settled >= SETTLED_FRAMES
            found = search_grid(
                lambda poses: self._similarity(local, predicted[3:6], poses),
                start_cells(START_REACH_M if local_search else np.inf),
                SURE_SIMILARITY,
            )
            dx, dy, turn = found.pose
            box[:3] = from_box_frame(np.array([[dx, dy, 0.0]]), predicted)[0]
            box[YAW] = wrap(predicted[YAW] + turn)
            confidence = float(np.clip(found.similarity, 0.0, 1.0))
            self.candidates_scored += found.candidates
            predicted_well = max(abs(dx), abs(dy)) <= SETTLED_REACH_M + 1e-9
            sure = found.similarity >= SURE_SIMILARITY and predicted_well
            self.settled = self.settled + 1 if sure else 0
        else:
            self.settled = 0
        target = in_box(around, box)
        self._remember(target)
        self.motion.update(box)
        self.box = box
        return TrackStep(box, confidence, len(target), predicted)

    def reset(self, points: np.ndarray, box: np.ndarray) -> np.ndarray:
        self.box = np.asarray(box, dtype=np.float64).copy()
        self.motion.relocate(self.box)
        self._remember(in_box(points, self.box))
        self.settled = 0
        return self.box

    def appearance(self, points: np.ndarray, box: np.ndarray) -> float:
        target = in_box(points, box)
        if len(target) < 3:
            return 0.0
        return float(
            np.clip(
                self._encode(sample_points(target, POINTS, self.rng)[None])[0] @ self.latent,
                0.0,
                1.0,
            )
        )
