"""Headset sync: an inspection's state after a cursor, and batches of offline judgments.

A cursor is a position in the change log (``changes.seq``, one row per change to a
synced entity). From no cursor the client gets a snapshot of the inspection (its
defects in id order, in pages, with their judgments) and then every change after the
log position the snapshot started at; the same entity may come twice, and clients
upsert by id.

On PostgreSQL two transactions may take log positions in one order and commit in the
other, so a reader can briefly see position n + 1 without n. The cursor never passes such
a hole while it is younger than ``GAP_SETTLE_S``: what is still committing is read next
time. (A hole left by a rolled-back transaction delays the cursor by that much once.)
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import bindparam, select, text, update
from sqlalchemy.engine import Row
from sqlalchemy.orm import Session

from contract.findings import stored_state
from supervisor.db import Database
from supervisor.defects.service import READING_KEYS, reading
from supervisor.engine.registry import all_kinds
from supervisor.exports.etag import scene_etag
from supervisor.inspections.schemas import InspectionOut
from supervisor.judgments.consensus import consensus_docs
from supervisor.judgments.service import judgment_out
from supervisor.judgments.write import JudgmentWrite, same_type_refusal, write
from supervisor.models import (
    Change,
    Defect,
    Inspection,
    Job,
    Judgment,
    SyncReceipt,
    User,
)
from supervisor.models._types import utcnow
from supervisor.problems import Problem, not_found
from supervisor.sync.schemas import OfflineJudgment

GAP_SETTLE_S = 10.0
MAX_CLOCK_AHEAD_S = 300.0
RECENT_CHANGES = 1000
DEFAULT_PAGE = 20_000
MAX_PAGE = 50_000

_CURSOR_PREFIX = "sync2"
"""A cursor names its inspection (``sync2:<inspection>:<seq>[:<defect id>]``): one given
for another inspection, or in the older format without it, is refused."""


@dataclass(frozen=True)
class Cursor:
    inspection_id: int
    seq: int
    """Every change up to this log position is in the client's copy (or in the snapshot)."""
    snapshot_after: int | None = None
    """During a snapshot: the last defect id sent; None once the snapshot is done."""


def encode_cursor(cursor: Cursor) -> str:
    parts = [_CURSOR_PREFIX, str(cursor.inspection_id), str(cursor.seq)]
    if cursor.snapshot_after is not None:
        parts.append(str(cursor.snapshot_after))
    return base64.urlsafe_b64encode(":".join(parts).encode()).decode().rstrip("=")


def decode_cursor(value: str | None, inspection_id: int) -> Cursor | None:
    """None for a full sync (no cursor, or ``0``); 400 for a cursor not given out for
    this inspection."""
    if not value or value == "0":
        return None
    try:
        raw = base64.urlsafe_b64decode(value + "=" * (-len(value) % 4)).decode()
        prefix, *numbers = raw.split(":")
        if prefix != _CURSOR_PREFIX or len(numbers) not in (2, 3):
            raise ValueError(raw)
        ints = [int(n) for n in numbers]
        if any(n < 0 for n in ints):
            raise ValueError(raw)
    except (ValueError, binascii.Error, UnicodeDecodeError) as exc:
        raise Problem(
            400, "since: not a cursor this server gave out; sync from the start (since=0)."
        ) from exc
    if ints[0] != inspection_id:
        raise Problem(
            400,
            f"since: this cursor belongs to inspection {ints[0]}, not {inspection_id}; "
            "sync this inspection from the start (since=0).",
        )
    return Cursor(ints[0], ints[1], ints[2] if len(ints) == 3 else None)


# --- reading -----------------------------------------------------------------------


def _settled(rows: Sequence, after_seq: int, now: datetime) -> list:
    """The leading rows that have no young hole before them (see the module docstring)."""
    settled, expected = [], after_seq + 1
    for row in rows:
        if row.seq != expected and (now - row.created_at).total_seconds() < GAP_SETTLE_S:
            break
        settled.append(row)
        expected = row.seq + 1
    return settled


def _high_water(session: Session, now: datetime) -> int:
    recent = session.execute(
        select(Change.seq, Change.created_at).order_by(Change.seq.desc()).limit(RECENT_CHANGES)
    ).all()[::-1]
    if not recent:
        return 0
    first = recent[0].seq - 1
    settled = _settled(recent, first, now)
    return settled[-1].seq if settled else first


_DEFECT_COLUMNS = (
    Defect.id,
    Defect.run_id,
    Defect.type,
    Defect.status,
    Defect.severity,
    Defect.value_mm,
    Defect.tolerance_mm,
    Defect.location_mm,
    Defect.normal,
    Defect.extent_mm,
    Defect.confidence,
    Defect.source,
    Defect.measurements,
    Defect.created_at,
    Defect.lineage_id,
    Defect.supersedes_id,
    Defect.superseded_by_id,
    Defect.ended,
    Defect.ended_run_id,
    Defect.notes,
)
LINEAGE_KEYS = ("lineage_id", "supersedes_id", "superseded_by_id", "ended", "ended_run_id")
"""Sent only for a finding in a line across measurements: absent, each is null (and the
lineage its own id). 10 000 findings measured once save a megabyte of a full sync."""
_JUDGMENT_COLUMNS = (
    Judgment.defect_id,
    Judgment.user_id,
    User.username,
    Judgment.verdict,
    Judgment.new_type,
    Judgment.comment,
    Judgment.revision,
    Judgment.updated_at,
    Judgment.client_time,
    Judgment.judged_on_run_id,
)


def _defect_doc(row) -> dict:  # noqa: ANN001 - a result row
    """A defect as a headset keeps it: its value, unit and tolerance once (not again in
    `measurements`), its creation time to the second, its lineage only where it has one."""
    doc = row._asdict()
    if doc["supersedes_id"] is None and doc["ended"] is None:  # measured once (most)
        for key in LINEAGE_KEYS:
            del doc[key]
    if not doc["notes"]:  # most have none
        del doc["notes"]
    measurements = doc.pop("measurements") or {}
    read = reading(doc.pop("value_mm"), doc.pop("tolerance_mm"), measurements)
    return {
        **doc,
        **read,
        "tolerance_state": stored_state(doc["severity"], measurements),
        "measurements": {k: v for k, v in measurements.items() if k not in READING_KEYS},
        "created_at": doc["created_at"].isoformat(timespec="seconds"),
    }


def _judgment_doc(row, username: str) -> dict:  # noqa: ANN001 - a result row or a Judgment
    return judgment_out(row, username).model_dump(mode="json")


def _judgments_of(session: Session, defect_ids: list[int]) -> list:
    if not defect_ids:
        return []
    return session.execute(
        select(*_JUDGMENT_COLUMNS)
        .join(User, User.id == Judgment.user_id)
        .where(Judgment.defect_id.in_(bindparam("ids", expanding=True)))
        .order_by(Judgment.defect_id, Judgment.user_id),
        {"ids": defect_ids},
    ).all()


def _inspection_doc(inspection: Inspection) -> dict:
    return InspectionOut.model_validate(inspection).model_dump(mode="json")


def changes_since(
    session: Session, *, inspection_id: int, cursor: Cursor | None, limit: int, scene_points: int
) -> dict:
    """One page of what changed in the inspection after ``cursor`` (None: everything)."""
    now = utcnow()
    inspection = session.get(Inspection, inspection_id)
    if inspection is None or inspection.deleted_at is not None:
        if cursor is not None:  # a device that had it: tell it to drop its copy
            raise Problem(410, f"Inspection {inspection_id} was deleted; drop its local copy.")
        raise not_found("inspection", inspection_id)
    if cursor is None:
        cursor = Cursor(inspection_id, _high_water(session, now), snapshot_after=0)
    if cursor.snapshot_after is not None:
        page = _snapshot_page(session, inspection, cursor, limit)
    else:
        page = _change_page(session, inspection, cursor, limit, now)
    page["scene_etag"] = scene_etag(session, inspection_id=inspection_id, max_points=scene_points)
    page["job_scenes"] = job_scenes(session, inspection_id)
    page["warnings"] = job_warnings(session, inspection_id)
    return page


def _succeeded_jobs(
    session: Session, inspection_id: int, *columns, kinds: list[str] | None = None
) -> list:
    """The inspection's succeeded jobs (of ``kinds``), newest first: id, run, kind, step
    and ``columns``."""
    query = select(Job.id, Job.run_id, Job.kind, Job.step, *columns).where(
        Job.inspection_id == inspection_id, Job.status == "succeeded"
    )
    if kinds is not None:
        query = query.where(Job.kind.in_(kinds))
    return session.execute(query.order_by(Job.id.desc())).all()


def _job_ref(job) -> dict:  # noqa: ANN001 - a result row
    return {"job_id": job.id, "run_id": job.run_id, "kind": job.kind, "step": job.step}


def job_warnings(session: Session, inspection_id: int) -> list[dict]:
    """The inspection's succeeded jobs whose results carry a warning (seams a measurement
    left unmeasured, and why), newest first: what a headset shows before anyone signs."""
    return [
        {
            **_job_ref(j),
            "warning": warning,
            "unmeasured_seams": (j.result or {}).get("unmeasured_seams"),
        }
        for j in _succeeded_jobs(session, inspection_id, Job.result)
        if isinstance(warning := (j.result or {}).get("warning"), str)
    ]


def job_scenes(session: Session, inspection_id: int) -> list[dict]:
    """The inspection's finished jobs that have a 3D scene (a trajectory, depth clouds, a
    track), newest first: what a headset lists beside the inspection's scene."""
    with_scene = [k.name for k in all_kinds() if k.shows.scene is not None]
    return [
        {
            **_job_ref(j),
            "finished_at": j.finished_at.isoformat() if j.finished_at else None,
            "url": f"/api/v1/jobs/{j.id}/scene.glb",
        }
        for j in _succeeded_jobs(session, inspection_id, Job.finished_at, kinds=with_scene)
    ]


def _snapshot_page(session: Session, inspection: Inspection, cursor: Cursor, limit: int) -> dict:
    rows = session.execute(
        select(*_DEFECT_COLUMNS)
        .where(Defect.inspection_id == inspection.id, Defect.id > cursor.snapshot_after)
        .order_by(Defect.id)
        .limit(limit + 1)
    ).all()
    more = len(rows) > limit
    rows = rows[:limit]
    defect_ids = [r.id for r in rows]
    judgments = _judgments_of(session, defect_ids)
    judged = sorted({j.defect_id for j in judgments})
    after = Cursor(inspection.id, cursor.seq, rows[-1].id if more else None)
    return {
        "inspection": _inspection_doc(inspection) if cursor.snapshot_after == 0 else None,
        "defects": [_defect_doc(r) for r in rows],
        "judgments": [_judgment_doc(j, j.username) for j in judgments],
        "consensus": consensus_docs(session, judged),
        "next_cursor": encode_cursor(after),
        "more": more,
    }


def _change_page(
    session: Session, inspection: Inspection, cursor: Cursor, limit: int, now: datetime
) -> dict:
    # The whole log after the cursor, not only this inspection's rows: a hole is a hole
    # whichever inspection the missing row belongs to.
    rows = (
        session.execute(
            select(Change).where(Change.seq > cursor.seq).order_by(Change.seq).limit(limit + 1)
        )
        .scalars()
        .all()
    )
    settled = _settled(rows[:limit], cursor.seq, now)
    more = len(rows) > limit and len(settled) == limit
    mine = [c for c in settled if c.inspection_id == inspection.id]
    defect_ids = sorted({c.entity_id for c in mine if c.entity == "defect"})
    judged_pairs = {(c.entity_id, c.user_id) for c in mine if c.entity == "judgment"}
    inspection_changed = any(c.entity == "inspection" for c in mine)
    defects = (
        session.execute(
            select(*_DEFECT_COLUMNS)
            .where(Defect.id.in_(bindparam("ids", expanding=True)))
            .order_by(Defect.id),
            {"ids": defect_ids},
        ).all()
        if defect_ids
        else []
    )
    judged_defects = sorted({d for d, _ in judged_pairs})
    judgments = [
        j
        for j in _judgments_of(session, judged_defects)
        if (j.defect_id, j.user_id) in judged_pairs
    ]
    last = settled[-1].seq if settled else cursor.seq
    return {
        "inspection": _inspection_doc(inspection) if inspection_changed else None,
        "defects": [_defect_doc(r) for r in defects],
        "judgments": [_judgment_doc(j, j.username) for j in judgments],
        "consensus": consensus_docs(session, judged_defects),
        "next_cursor": encode_cursor(Cursor(inspection.id, last)),
        "more": more,
    }


# --- offline judgments ---------------------------------------------------------------


def _digest(item: OfflineJudgment) -> str:
    content = item.model_dump(mode="json", exclude={"client_id"})
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def _same_content(judgment: Row, item: OfflineJudgment) -> bool:
    return (judgment.verdict, judgment.new_type, judgment.comment) == (
        item.verdict,
        item.new_type,
        item.comment,
    )


_JUDGMENTS = Judgment.__table__
_MINE = (  # locked on PostgreSQL (SQLite has one writer anyway)
    select(_JUDGMENTS)
    .where(
        _JUDGMENTS.c.user_id == bindparam("user_id"),
        _JUDGMENTS.c.defect_id.in_(bindparam("ids", expanding=True)),
    )
    .with_for_update()
)
_TOUCH = (  # the same judgment again, made later: only its time moves
    update(_JUDGMENTS)
    .where(
        _JUDGMENTS.c.user_id == bindparam("judge"),
        _JUDGMENTS.c.defect_id == bindparam("defect"),
    )
    .values(client_time=bindparam("made_at"))
    .returning(*_JUDGMENTS.c)
)


def apply_batch(
    db: Database, *, user_id: int, username: str, items: list[OfflineJudgment]
) -> tuple[list[dict], list[dict]]:
    """Apply a batch of offline judgments of one user; returns (results, consensus docs).

    A user's batches run one at a time (a lock per user on PostgreSQL; SQLite has one
    writer), so a retried batch racing its first attempt replays instead of applying
    twice. Each judgment goes through the one judgment write, which keeps a stored
    judgment made later (a concurrent PUT, say).
    """
    with db.write() as session:
        if not db.is_sqlite:
            session.execute(
                text("SELECT pg_advisory_xact_lock(7413, :user_id)"), {"user_id": user_id}
            )
        return _apply(session, user_id=user_id, username=username, items=items)


def _apply(
    session: Session, *, user_id: int, username: str, items: list[OfflineJudgment]
) -> tuple[list[dict], list[dict]]:
    now = utcnow()
    client_ids = list({item.client_id for item in items})
    receipts = {
        r.client_id: r
        for r in session.scalars(
            select(SyncReceipt).where(
                SyncReceipt.user_id == user_id,
                SyncReceipt.client_id.in_(bindparam("ids", expanding=True)),
            ),
            {"ids": client_ids},
        )
    }
    landing = _landings(session, list({item.defect_id for item in items}))
    ids = list({landing.get(item.defect_id, Landing(item.defect_id)).defect_id for item in items})
    current = {j.defect_id: j for j in session.execute(_MINE, {"user_id": user_id, "ids": ids})}
    homes = _homes(session, ids)
    results = []
    for sent in items:
        digest = _digest(sent)
        lands = landing.get(sent.defect_id, Landing(sent.defect_id))
        item = sent.model_copy(update={"defect_id": lands.defect_id})
        result = {
            "client_id": sent.client_id,
            "defect_id": sent.defect_id,
            "replayed": False,
            "landed_on": None,
        }
        receipt = receipts.get(sent.client_id)
        status, detail = None, None
        if receipt is not None:
            if receipt.request_sha256 != digest or receipt.defect_id != sent.defect_id:
                status = "rejected"
                detail = f"client_id {sent.client_id} was already used for another judgment."
            else:
                status, result["replayed"] = receipt.status, True
        else:
            refusal = lands.refusal or _misplaced(item, homes.get(item.defect_id))
            if refusal is not None:
                status, detail = "rejected", refusal
            else:
                status, detail = _apply_one(session, item, current, user_id, now, lands)
            if status != "rejected":
                receipt = SyncReceipt(
                    user_id=user_id,
                    client_id=sent.client_id,
                    defect_id=sent.defect_id,
                    request_sha256=digest,
                    status=status,
                    revision=current[item.defect_id].revision,
                )
                session.add(receipt)
                receipts[sent.client_id] = receipt
        judgment = current.get(item.defect_id) if status != "rejected" else None
        if judgment is not None and item.defect_id != sent.defect_id:
            result["landed_on"] = item.defect_id
            detail = detail or lands.note
        result["status"], result["detail"] = status, detail
        result["judgment"] = _judgment_doc(judgment, username) if judgment is not None else None
        results.append(result)
    session.flush()
    touched = sorted(
        {r["landed_on"] or r["defect_id"] for r in results if r["status"] == "applied"}
    )
    return results, consensus_docs(session, touched)


@dataclass(frozen=True)
class Landing:
    """Where a verdict sent for a finding lands: the finding, or the current successor of
    one a later measurement superseded (judged on the run of the one sent for)."""

    defect_id: int
    judged_on_run_id: int | None = None
    refusal: str | None = None
    note: str | None = None


def _landings(session: Session, defect_ids: list[int]) -> dict[int, Landing]:
    """The landing of each finding sent for that a later measurement ended (others land
    on themselves)."""
    rows = {}
    wanted = set(defect_ids)
    while wanted:  # follow each line to its end; lines are as long as re-measurements
        found = session.execute(
            select(
                Defect.id, Defect.run_id, Defect.superseded_by_id, Defect.ended, Defect.ended_run_id
            ).where(Defect.id.in_(bindparam("ids", expanding=True))),
            {"ids": sorted(wanted)},
        ).all()
        rows.update({r.id: r for r in found})
        wanted = {r.superseded_by_id for r in found if r.superseded_by_id} - set(rows)
    landings = {}
    for sent in defect_ids:
        first = rows.get(sent)
        if first is None or first.ended is None:
            continue
        last = first
        while last.ended == "superseded" and last.superseded_by_id in rows:
            last = rows[last.superseded_by_id]
        if last.ended == "not found again":
            landings[sent] = Landing(
                sent,
                refusal=f"Finding {sent} was not found again by the measurement of run "
                f"{last.ended_run_id}: your judgment is set aside (see the finding's history).",
            )
        else:
            landings[sent] = Landing(
                last.id,
                judged_on_run_id=first.run_id,
                note=f"Finding {sent} was measured again by run {first.ended_run_id}: your "
                f"judgment landed on its successor, finding {last.id}, marked as judged on "
                f"run {first.run_id}.",
            )
    return landings


def _homes(session: Session, defect_ids: list[int]) -> dict[int, tuple[int, bool]]:
    """Each existing defect's (inspection id, inspection in the trash)."""
    rows = session.execute(
        select(Defect.id, Defect.inspection_id, Inspection.deleted_at.is_not(None))
        .join(Inspection, Inspection.id == Defect.inspection_id)
        .where(Defect.id.in_(bindparam("ids", expanding=True))),
        {"ids": defect_ids},
    )
    return {defect_id: (inspection_id, bool(trashed)) for defect_id, inspection_id, trashed in rows}


def _misplaced(item: OfflineJudgment, home: tuple[int, bool] | None) -> str | None:
    """Why the item cannot be for the defect it names, or None."""
    if home is None:
        return (
            f"There is no defect with id {item.defect_id} (deleted, or never on this server); "
            "your judgment is set aside."
        )
    inspection_id, trashed = home
    if trashed:
        return f"Inspection {inspection_id} was deleted; your judgment is set aside."
    if item.inspection_id is not None and item.inspection_id != inspection_id:
        return (
            f"Defect {item.defect_id} is in inspection {inspection_id}, not in inspection "
            f"{item.inspection_id} you judged it in: your judgment is set aside."
        )
    return None


def _kept(judgment: Row | None, item: OfflineJudgment) -> tuple[str, str | None] | None:
    """``stale`` when the stored judgment was made after this one, ``unchanged`` when it
    says the same; None when this one is to be written."""
    if judgment is None:
        return None
    if judgment.client_time is not None and judgment.client_time >= item.client_time:
        return "stale", (
            f"your judgment of defect {item.defect_id} made at "
            f"{judgment.client_time.isoformat()} is newer and stays."
        )
    if _same_content(judgment, item):
        return "unchanged", None
    return None


def _apply_one(
    session: Session,
    item: OfflineJudgment,
    current: dict[int, Row],
    user_id: int,
    now: datetime,
    lands: Landing,
) -> tuple[str, str | None]:
    ahead_s = (item.client_time - now).total_seconds()
    if ahead_s > MAX_CLOCK_AHEAD_S:
        return "rejected", (
            f"client_time is {ahead_s:.0f} s ahead of the server's clock "
            f"(at most {MAX_CLOCK_AHEAD_S:.0f} s allowed): set the device's clock."
        )
    kept = _kept(current.get(item.defect_id), item)
    if kept is None:
        written = write(
            session,
            JudgmentWrite.of(
                item,
                defect_id=item.defect_id,
                user_id=user_id,
                client_time=item.client_time,
                now=now,
                newer_only=True,
                judged_on_run_id=lands.judged_on_run_id,
            ),
        )
        if written.defect_type is None:
            return "rejected", f"There is no defect with id {item.defect_id}."
        if written.refused:
            return "rejected", same_type_refusal(written.defect_type)
        assert written.judgment is not None
        current[item.defect_id] = written.judgment
        if written.changed:
            return "applied", None
        kept = _kept(written.judgment, item)  # a judgment stored meanwhile
        assert kept is not None
    if kept[0] == "unchanged":
        params = {"judge": user_id, "defect": item.defect_id, "made_at": item.client_time}
        current[item.defect_id] = session.execute(_TOUCH, params).one()
    return kept
