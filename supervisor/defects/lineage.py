"""A new measurement of an area supersedes the last: ``supersede``.

Each finding of the new job is matched to a current finding of an earlier measurement of
the same kind in the same inspection (``match``): a seam's finding to the same type on
the same seam (parallel, its line within ``SEAM_OFFSET_MM``) near the same place along it,
any other finding (a surface defect, a junction's mismatch) to the same type where their
extents overlap. A match continues the earlier finding's line: it takes its lineage, its
status where a person set one, and copies of its judgments with every revision, each
marked with the run it was judged on; the earlier finding ends, ``superseded``. An earlier
piece of one defect (found in two pieces before, in one now) ends ``superseded`` by the
same new finding; an earlier finding inside the new cloud's bounds that nothing matched
ends ``not found again``; one
outside them (another area of the part) stays current. Findings reported by hand are
never ended by a measurement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from sqlalchemy import bindparam, insert, select, update
from sqlalchemy.orm import Session

from contract.findings import SeamMeasurements, measurements_of
from supervisor.changes import record_change
from supervisor.models import Defect, Job, Judgment, JudgmentRevision

SEAM_OFFSET_MM = 5.0
"""Largest distance of an earlier seam's middle from the new seam's line: the same seam."""
SEAM_COS = float(np.cos(np.radians(10.0)))
"""Two seams more than 10° apart are not the same seam."""
ALONG_MM = 25.0
"""Largest move along a seam of a finding's place (the worst section moves with the noise)
beyond half the two findings' extents."""
OVERLAP_MARGIN_MM = 3.0
"""Two findings off a seam are the same where their extents overlap, or nearly."""
COVER_MARGIN_MM = 5.0
"""An earlier finding this far outside the new cloud's box is still inside its area."""


@dataclass(frozen=True)
class Placed:
    """A finding as matching sees it."""

    id: int
    type: str
    location_mm: np.ndarray
    extent_mm: float
    seam_mm: np.ndarray | None
    """(2, 3): the ends of the seam it lies on; None off a seam."""


@dataclass(frozen=True)
class Superseded:
    matched: dict[int, int]
    """New finding id → the earlier finding it continues."""
    pieces: dict[int, int]
    """Earlier finding id → the new finding it is a piece of (found in two pieces before)."""
    not_found: list[int]
    """Earlier findings inside the new cloud's area that nothing matched."""


def _candidates(old: list[Placed], new: list[Placed]) -> list[tuple[float, int, int]]:
    """Every (distance, new id, old id) the rules allow, nearest first."""
    pairs: list[tuple[float, int, int]] = []
    for kind in {p.type for p in new} & {p.type for p in old}:
        olds = [p for p in old if p.type == kind]
        news = [p for p in new if p.type == kind]
        pairs += _seam_pairs(
            [p for p in olds if p.seam_mm is not None], [p for p in news if p.seam_mm is not None]
        )
        pairs += _overlap_pairs(
            [p for p in olds if p.seam_mm is None], [p for p in news if p.seam_mm is None]
        )
    return sorted(pairs)


def match(old: list[Placed], new: list[Placed]) -> dict[int, int]:
    """New finding id → old finding id, one to one, nearest pairs first."""
    matched: dict[int, int] = {}
    taken: set[int] = set()
    for _, new_id, old_id in _candidates(old, new):
        if new_id not in matched and old_id not in taken:
            matched[new_id] = old_id
            taken.add(old_id)
    return matched


def pieces(old: list[Placed], new: list[Placed], matched: dict[int, int]) -> dict[int, int]:
    """Earlier findings left over by ``match`` that the same rules put on a new finding
    (one defect found in two pieces before, in one now): old id → new id, nearest."""
    taken = set(matched.values())
    merged: dict[int, int] = {}
    for _, new_id, old_id in _candidates([p for p in old if p.id not in taken], new):
        merged.setdefault(old_id, new_id)
    return merged


def _seam_pairs(old: list[Placed], new: list[Placed]) -> list[tuple[float, int, int]]:
    """Pairs on the same seam, near the same place along it: (distance, new id, old id)."""
    if not old or not new:
        return []
    old_seams = np.stack([p.seam_mm for p in old])  # (m, 2, 3)
    new_seams = np.stack([p.seam_mm for p in new])  # (n, 2, 3)
    new_dir = new_seams[:, 1] - new_seams[:, 0]
    new_len = np.linalg.norm(new_dir, axis=1)
    new_dir = new_dir / np.maximum(new_len, 1e-9)[:, None]
    old_dir = old_seams[:, 1] - old_seams[:, 0]
    old_dir = old_dir / np.maximum(np.linalg.norm(old_dir, axis=1), 1e-9)[:, None]
    parallel = np.abs(new_dir @ old_dir.T) >= SEAM_COS  # (n, m)
    middle = old_seams.mean(axis=1)  # (m, 3)
    offset = middle[None, :, :] - new_seams[:, None, 0, :]
    along_middle = np.einsum("nmk,nk->nm", offset, new_dir)
    off_line = np.linalg.norm(offset - along_middle[..., None] * new_dir[:, None, :], axis=2)
    new_at = np.stack([p.location_mm for p in new])
    old_at = np.stack([p.location_mm for p in old])
    moved = old_at[None, :, :] - new_at[:, None, :]
    along_moved = np.abs(np.einsum("nmk,nk->nm", moved, new_dir))
    reach = ALONG_MM + 0.5 * (
        np.array([p.extent_mm for p in new])[:, None] + np.array([p.extent_mm for p in old])
    )
    same = parallel & (off_line <= SEAM_OFFSET_MM) & (along_moved <= reach)
    rows, cols = np.nonzero(same)
    distance = np.linalg.norm(moved[rows, cols], axis=1)
    return [(float(d), new[r].id, old[c].id) for d, r, c in zip(distance, rows, cols, strict=True)]


def _overlap_pairs(old: list[Placed], new: list[Placed]) -> list[tuple[float, int, int]]:
    """Pairs whose extents (discs about their places) overlap: (distance, new id, old id)."""
    if not old or not new:
        return []
    old_at = np.stack([p.location_mm for p in old])
    new_at = np.stack([p.location_mm for p in new])
    old_r = 0.5 * np.array([p.extent_mm for p in old])
    new_r = 0.5 * np.array([p.extent_mm for p in new])
    radius = float(old_r.max() + new_r.max() + OVERLAP_MARGIN_MM)
    near = cKDTree(new_at).query_ball_tree(cKDTree(old_at), radius)
    rows = np.repeat(np.arange(len(new)), [len(n) for n in near])
    cols = np.array([c for n in near for c in n], dtype=int)
    if not len(cols):
        return []
    distance = np.linalg.norm(new_at[rows] - old_at[cols], axis=1)
    keep = distance <= new_r[rows] + old_r[cols] + OVERLAP_MARGIN_MM
    return [
        (float(d), new[r].id, old[c].id)
        for d, r, c in zip(distance[keep], rows[keep], cols[keep], strict=True)
    ]


def _placed(row) -> Placed:  # noqa: ANN001 - a result row
    found = measurements_of(row.type, row.measurements)
    seam = found.seam_mm if isinstance(found, SeamMeasurements) else None
    return Placed(
        id=row.id,
        type=row.type,
        location_mm=np.asarray(row.location_mm, dtype=float),
        extent_mm=float(row.extent_mm or 0.0),
        seam_mm=np.asarray(seam, dtype=float) if seam is not None else None,
    )


def _inside(row, bounds: list | None) -> bool:  # noqa: ANN001 - a result row
    if bounds is None:
        return True
    at = np.asarray(row.location_mm, dtype=float)
    low, high = np.asarray(bounds[0]) - COVER_MARGIN_MM, np.asarray(bounds[1]) + COVER_MARGIN_MM
    return bool(np.all(at >= low) and np.all(at <= high))


_PLACED_COLUMNS = (
    Defect.id,
    Defect.type,
    Defect.location_mm,
    Defect.extent_mm,
    Defect.measurements,
    Defect.run_id,
)


def supersede(session: Session, *, job_id: int) -> Superseded:
    """Match the findings job ``job_id`` just recorded to the current ones of earlier
    measurements of its kind in its inspection, carry what people said, end the rest (see
    the module docstring). In the job's own transaction."""
    job = session.execute(
        select(Job.inspection_id, Job.run_id, Job.kind, Job.result).where(Job.id == job_id)
    ).one()
    bounds = (job.result or {}).get("cloud_bounds_mm")
    new_rows = session.execute(select(*_PLACED_COLUMNS).where(Defect.job_id == job_id)).all()
    earlier_jobs = select(Job.id).where(
        Job.inspection_id == job.inspection_id, Job.kind == job.kind, Job.id != job_id
    )
    old_rows = [
        row
        for row in session.execute(
            select(*_PLACED_COLUMNS).where(
                Defect.inspection_id == job.inspection_id,
                Defect.source == "job",
                Defect.ended.is_(None),
                Defect.job_id.in_(earlier_jobs),
            )
        ).all()
        if _inside(row, bounds)
    ]
    if not old_rows:
        return Superseded({}, {}, [])
    old, new = [_placed(r) for r in old_rows], [_placed(r) for r in new_rows]
    matched = match(old, new)
    merged = pieces(old, new, matched)
    not_found = sorted({r.id for r in old_rows} - set(matched.values()) - set(merged))
    _carry(session, matched, merged, job.run_id, job.inspection_id)
    if not_found:
        session.execute(
            update(Defect)
            .where(Defect.id.in_(bindparam("ids", expanding=True)))
            .values(ended="not found again", ended_run_id=job.run_id),
            {"ids": not_found},
        )
    for old_id in [*matched.values(), *merged, *not_found]:
        record_change(
            session, entity="defect", entity_id=old_id, op="update", inspection_id=job.inspection_id
        )
    return Superseded(matched, merged, not_found)


def _carry(
    session: Session,
    matched: dict[int, int],
    merged: dict[int, int],
    run_id: int | None,
    inspection_id: int,
) -> None:
    """Each new finding continues its earlier one (lineage, status, judgments); an earlier
    piece of it ends too, its judgments kept where the new one has none of that user."""
    new_of = {old: new for new, old in matched.items()} | merged
    if not new_of:
        return
    defects = Defect.__table__
    olds = {
        d.id: d
        for d in session.execute(
            select(
                defects.c.id,
                defects.c.lineage_id,
                defects.c.run_id,
                defects.c.status,
                defects.c.status_by,
                defects.c.status_reason,
            ).where(defects.c.id.in_(bindparam("ids", expanding=True))),
            {"ids": list(new_of)},
        )
    }
    session.execute(
        update(defects)
        .where(defects.c.id == bindparam("old_id"))
        .values(superseded_by_id=bindparam("new_id"), ended="superseded", ended_run_id=run_id),
        [{"old_id": old, "new_id": new} for old, new in new_of.items()],
    )
    if matched:
        session.execute(
            update(defects)
            .where(defects.c.id == bindparam("new_id"))
            .values(
                lineage_id=bindparam("lineage"),
                supersedes_id=bindparam("old_id"),
                status=bindparam("carried_status"),
                status_by=bindparam("carried_by"),
                status_reason=bindparam("carried_reason"),
            ),
            [_carried_status(olds[old], new) for new, old in matched.items()],
        )
    main = set(matched.values())
    _copy_judgments(session, new_of, main, {i: d.run_id for i, d in olds.items()}, inspection_id)


def _carried_status(old, new_id: int) -> dict:  # noqa: ANN001 - a result row
    """A dismissal stands (the reason is the person's); a finding resolved (repaired) but
    measured again is open again, saying so."""
    status, by, reason = old.status, old.status_by, old.status_reason
    if status == "resolved":
        status, reason = "open", f"resolved as finding {old.id}, and measured again since"
    return {
        "new_id": new_id,
        "old_id": old.id,
        "lineage": old.lineage_id or old.id,
        "carried_status": status,
        "carried_by": by,
        "carried_reason": reason,
    }


def _copy_judgments(
    session: Session,
    new_of: dict[int, int],
    main: set[int],
    run_of: dict[int, int | None],
    inspection_id: int,
) -> None:
    """Copies of the earlier findings' judgments and every revision on their successors,
    each marked with the run it was judged on (kept where it was carried before). Of one
    user's judgments of several pieces, the main finding's wins, else the newest."""
    judgments, revisions = Judgment.__table__, JudgmentRevision.__table__
    rows = (
        session.execute(
            select(judgments).where(judgments.c.defect_id.in_(bindparam("ids", expanding=True))),
            {"ids": list(new_of)},
        )
        .mappings()
        .all()
    )
    chosen: dict[tuple[int, int], dict] = {}
    for row in sorted(
        rows, key=lambda r: (r["defect_id"] not in main, -(r["updated_at"].timestamp()))
    ):
        chosen.setdefault((new_of[row["defect_id"]], row["user_id"]), row)
    if not chosen:
        return
    sources = {(row["defect_id"], row["user_id"]) for row in chosen.values()}
    history = [
        row
        for row in session.execute(
            select(revisions).where(revisions.c.defect_id.in_(bindparam("ids", expanding=True))),
            {"ids": sorted({d for d, _ in sources})},
        ).mappings()
        if (row["defect_id"], row["user_id"]) in sources
    ]
    for table, copied in ((judgments, list(chosen.values())), (revisions, history)):
        session.execute(
            insert(table),
            [
                {
                    **{k: v for k, v in row.items() if k != "id"},
                    "defect_id": new_of[row["defect_id"]],
                    "judged_on_run_id": row["judged_on_run_id"] or run_of[row["defect_id"]],
                }
                for row in copied
            ],
        )
    for new_id, user_id in chosen:
        record_change(
            session,
            entity="judgment",
            entity_id=new_id,
            op="update",
            inspection_id=inspection_id,
            user_id=user_id,
        )
