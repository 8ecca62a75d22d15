"""A headset simulator: what the HoloLens client does, in Python, for tests and load.

A ``Headset`` keeps a local copy of one inspection (defects, judgments, consensus, the
scene's ETag and the sync cursor) and an outbox of judgments made offline. Judging works
with or without a connection: it updates the copy at once and queues the judgment with a
client-made id and the headset's clock. ``push`` sends the outbox in batches; an item the
server answered leaves the outbox, anything else (no network, a lost response) stays and
is sent again with the same id, which the server answers as the first time. A judgment is
checked before it is queued; an item the server refuses as malformed (an outbox written by
an older client) is set aside in ``refused`` with the reason and never holds back the rest.

    vista-headset --url http://127.0.0.1:8000 --token DEVICE_TOKEN --inspection 1 \\
        --judge 12=confirmed --judge 14=rejected --state headset.json
"""

from __future__ import annotations

import argparse
import json
import sys
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import httpx

from vista_client.client import VistaClient, VistaError

BATCH = 1000
VERDICTS = ("confirmed", "rejected", "reclassified", "uncertain")
DEFECT_TYPES = ("gap", "step", "parallelism", "mismatch", "scratch", "dent", "bump", "color")
MAX_COMMENT_CHARS = 4000


class HeadsetOffline(ConnectionError):
    """The headset has no connection (``go_offline``), or the network failed."""


@dataclass
class SyncReport:
    pages: int = 0
    defects: int = 0
    judgments: int = 0
    scene_changed: bool = False


@dataclass
class PushReport:
    sent: int = 0
    results: list[dict] = field(default_factory=list)
    refused: list[dict] = field(default_factory=list)
    """Items the server refused as malformed: set aside (``Headset.refused``), not sent again."""

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.results)


class Headset:
    def __init__(
        self,
        client: VistaClient,
        inspection_id: int,
        *,
        clock: Callable[[], datetime] = lambda: datetime.now(UTC),
    ) -> None:
        self.client = client
        self.inspection_id = inspection_id
        self.clock = clock
        self.online = True
        self.cursor: str | None = None
        self.inspection: dict | None = None
        self.defects: dict[int, dict] = {}
        self.judgments: dict[tuple[int, int], dict] = {}
        self.consensus: dict[int, dict] = {}
        self.scene_etag: str | None = None
        self.loaded_scene_etag: str | None = None
        self.outbox: list[dict] = []
        self.refused: list[dict] = []
        """Outbox items set aside: each with a ``reason``."""
        self.user: dict | None = None

    # -- connection ----------------------------------------------------------------------

    def go_offline(self) -> None:
        self.online = False

    def go_online(self) -> None:
        self.online = True

    def _call(self, fn: Callable, *args, **kwargs):  # noqa: ANN202
        if not self.online:
            raise HeadsetOffline("the headset is offline")
        try:
            return fn(*args, **kwargs)
        except httpx.TransportError as exc:
            raise HeadsetOffline(f"network failure: {exc}") from exc

    # -- pulling -------------------------------------------------------------------------

    def sync(self) -> SyncReport:
        """Pull every page that is waiting and fold it into the local copy."""
        if self.user is None:
            self.user = self._call(self.client.me)
        report = SyncReport()
        while True:
            page = self._call(self.client.sync, self.inspection_id, self.cursor)
            report.pages += 1
            if page["inspection"] is not None:
                self.inspection = page["inspection"]
            for defect in page["defects"]:
                self.defects[defect["id"]] = defect
            for judgment in page["judgments"]:
                self._keep_judgment(judgment)
            for consensus in page["consensus"]:
                self.consensus[consensus["defect_id"]] = consensus
            report.defects += len(page["defects"])
            report.judgments += len(page["judgments"])
            self.scene_etag = page["scene_etag"]
            self.cursor = page["next_cursor"]
            if not page["more"]:
                break
        report.scene_changed = self.scene_etag != self.loaded_scene_etag
        return report

    def _keep_judgment(self, judgment: dict) -> None:
        self.judgments[(judgment["defect_id"], judgment["user_id"])] = judgment

    def judgment_of(self, defect_id: int, user_id: int) -> dict | None:
        """A user's judgment of a defect as the headset shows it: this user's latest queued
        edit while it waits in the outbox, else the server's copy."""
        if self.user is not None and user_id == self.user["id"]:
            queued = [item for item in self.outbox if item["defect_id"] == defect_id]
            if queued:
                item = queued[-1]
                return {
                    "defect_id": defect_id,
                    "user_id": user_id,
                    "username": self.user["username"],
                    "verdict": item["verdict"],
                    "new_type": item.get("new_type"),
                    "comment": item["comment"],
                    "revision": None,
                    "updated_at": None,
                    "client_time": item["client_time"],
                }
        return self.judgments.get((defect_id, user_id))

    def load_scene(self) -> bytes | None:
        """Download scene.glb if it changed since the last download (None if not)."""
        data, etag = self._call(self.client.scene, self.inspection_id, etag=self.loaded_scene_etag)
        self.loaded_scene_etag = etag
        return data

    # -- judging -------------------------------------------------------------------------

    def judge(
        self,
        defect_id: int,
        verdict: str,
        *,
        new_type: str | None = None,
        comment: str = "",
        at: datetime | None = None,
    ) -> dict:
        """Judge a defect now, online or not: queued, and shown in the local copy. Raises
        ``ValueError`` naming the problem (nothing queued) for a judgment the server would
        refuse, ``KeyError`` for a defect the local copy does not hold."""
        problem = judgment_problem(verdict, new_type, comment)
        if problem:
            raise ValueError(f"defect {defect_id}: {problem}")
        if defect_id not in self.defects:
            raise KeyError(f"defect {defect_id} is not in this headset's copy; sync first")
        item = {
            "client_id": str(uuid.uuid4()),
            "defect_id": defect_id,
            "inspection_id": self.inspection_id,
            "verdict": verdict,
            "comment": comment,
            "client_time": (at or self.clock()).astimezone(UTC).isoformat(),
        }
        if new_type is not None:
            item["new_type"] = new_type
        self.outbox.append(item)
        return item

    def push(self) -> PushReport:
        """Send the outbox; answered items leave it, items the server refuses as malformed
        are set aside with the reason. Raises ``HeadsetOffline`` (the outbox kept whole)
        when the connection fails, ``VistaError`` when the server refuses the headset
        itself (401, 403)."""
        report = PushReport()
        self._set_aside(
            [
                (i, p)
                for i in self.outbox
                if (
                    p := judgment_problem(i.get("verdict"), i.get("new_type"), i.get("comment", ""))
                )
            ],
            report,
        )
        while self.outbox:
            batch = self.outbox[:BATCH]
            try:
                answer = self._call(self.client.push_judgments, batch)
            except VistaError as exc:
                if exc.status != 422:
                    raise
                self._push_one_by_one(batch, report)
                continue
            self._fold_answer(batch, answer, report)
        return report

    def _push_one_by_one(self, batch: list[dict], report: PushReport) -> None:
        """A batch refused as a whole: each item alone, so only the bad ones are set aside."""
        for item in batch:
            try:
                answer = self._call(self.client.push_judgments, [item])
            except VistaError as exc:
                if exc.status != 422:
                    raise
                self._set_aside([(item, exc.detail)], report)
                continue
            self._fold_answer([item], answer, report)

    def _fold_answer(self, batch: list[dict], answer: dict, report: PushReport) -> None:
        answered = {r["client_id"] for r in answer["results"]}
        self.outbox = [i for i in self.outbox if i["client_id"] not in answered]
        for result in answer["results"]:
            if result["judgment"] is not None:
                judgment = result["judgment"]
                self.judgments[(judgment["defect_id"], judgment["user_id"])] = judgment
        for consensus in answer["consensus"]:
            self.consensus[consensus["defect_id"]] = consensus
        report.sent += len(batch)
        report.results += answer["results"]

    def _set_aside(self, items: list[tuple[dict, str]], report: PushReport) -> None:
        gone = {id(item) for item, _ in items}
        self.outbox = [i for i in self.outbox if id(i) not in gone]
        for item, reason in items:
            refused = {**item, "reason": reason}
            self.refused.append(refused)
            report.refused.append(refused)

    # -- persistence ---------------------------------------------------------------------

    def save(self, path: Path) -> None:
        """Everything the headset knows, so it survives a restart while offline."""
        state = {
            "inspection_id": self.inspection_id,
            "cursor": self.cursor,
            "inspection": self.inspection,
            "defects": list(self.defects.values()),
            "judgments": list(self.judgments.values()),
            "consensus": list(self.consensus.values()),
            "scene_etag": self.scene_etag,
            "loaded_scene_etag": self.loaded_scene_etag,
            "outbox": self.outbox,
            "refused": self.refused,
            "user": self.user,
        }
        temp = Path(path).with_suffix(".tmp")
        temp.write_text(json.dumps(state))
        temp.replace(path)

    @classmethod
    def load(cls, client: VistaClient, path: Path, **kwargs) -> Headset:
        state = json.loads(Path(path).read_text())
        headset = cls(client, state["inspection_id"], **kwargs)
        headset.cursor = state["cursor"]
        headset.inspection = state["inspection"]
        headset.defects = {d["id"]: d for d in state["defects"]}
        headset.judgments = {(j["defect_id"], j["user_id"]): j for j in state["judgments"]}
        headset.consensus = {c["defect_id"]: c for c in state["consensus"]}
        headset.scene_etag = state["scene_etag"]
        headset.loaded_scene_etag = state["loaded_scene_etag"]
        headset.outbox = state["outbox"]
        headset.refused = state.get("refused", [])
        headset.user = state["user"]
        return headset


def judgment_problem(verdict: object, new_type: object, comment: object) -> str | None:
    """Why the server would refuse this judgment, or None."""
    if verdict not in VERDICTS:
        return f"verdict {verdict!r} is not one of {', '.join(VERDICTS)}"
    if verdict == "reclassified" and new_type not in DEFECT_TYPES:
        return f"reclassified needs a new type, one of {', '.join(DEFECT_TYPES)} (e.g. 12=reclassified:dent)"
    if verdict != "reclassified" and new_type is not None:
        return f"a new type is given only with 'reclassified', not with {verdict!r}"
    if not isinstance(comment, str) or len(comment) > MAX_COMMENT_CHARS:
        return f"the comment must be text of at most {MAX_COMMENT_CHARS} characters"
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="vista-headset",
        description="Sync one inspection like a headset: pull changes, queue judgments, push "
        "them. With --state the copy and the outbox persist between runs (offline work).",
    )
    parser.add_argument("--url", required=True, help="the supervisor, e.g. http://host:8000")
    parser.add_argument("--token", required=True, help="a device token (or any API token)")
    parser.add_argument("--inspection", type=int, required=True)
    parser.add_argument("--state", type=Path, help="JSON file with the headset's state")
    parser.add_argument(
        "--judge",
        action="append",
        default=[],
        metavar="DEFECT=VERDICT",
        help="queue a judgment, e.g. 12=confirmed or 12=reclassified:dent (repeatable)",
    )
    parser.add_argument("--offline", action="store_true", help="queue only; send nothing")
    args = parser.parse_args(argv)
    with VistaClient(args.url, args.token) as client:
        if args.state and args.state.exists():
            headset = Headset.load(client, args.state)
        else:
            headset = Headset(client, args.inspection)
        try:
            return _run(headset, args)
        except HeadsetOffline as exc:
            print(f"offline ({exc}); {len(headset.outbox)} judgment(s) wait", file=sys.stderr)
            return 0
        except VistaError as exc:
            print(f"error: the server answered {exc.status}: {exc.detail}", file=sys.stderr)
            return 1
        finally:
            if args.state:
                headset.save(args.state)


def _run(headset: Headset, args: argparse.Namespace) -> int:
    if not args.offline:
        pulled = headset.sync()
        print(
            f"synced {pulled.defects} defects, {pulled.judgments} judgments "
            f"in {pulled.pages} page(s); scene changed: {pulled.scene_changed}"
        )
    refused = 0
    for spec in args.judge:
        defect, _, verdict = spec.partition("=")
        verdict, _, new_type = verdict.partition(":")
        try:
            if not defect.strip().isdigit():
                raise ValueError(f"{defect!r} is not a defect id")
            headset.judge(int(defect), verdict, new_type=new_type or None)
        except (ValueError, KeyError) as exc:
            print(f"not queued: --judge {spec}: {exc.args[0]}", file=sys.stderr)
            refused += 1
    if not args.offline and headset.outbox:
        pushed = headset.push()
        summary = {s: pushed.count(s) for s in ("applied", "unchanged", "stale")}
        print(f"pushed {pushed.sent}: {summary}, rejected {pushed.count('rejected')}")
        for result in pushed.results:
            if result["status"] == "rejected":
                print(f"  defect {result['defect_id']}: {result['detail']}")
        for item in pushed.refused:
            print(
                f"  set aside (not sent again): defect {item.get('defect_id')} "
                f"{item.get('verdict')!r}: {item['reason']}",
                file=sys.stderr,
            )
    return 2 if refused else 0


if __name__ == "__main__":
    sys.exit(main())
