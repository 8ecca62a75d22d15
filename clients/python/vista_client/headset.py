"""A headset simulator: what the HoloLens client does, in Python, for tests and load.

A ``Headset`` keeps a local copy of one inspection (defects, judgments, consensus, the
scene's ETag and the sync cursor) and an outbox of judgments made offline. Judging works
with or without a connection: it updates the copy at once and queues the judgment with a
client-made id and the headset's clock. ``push`` sends the outbox in batches; an item the
server answered leaves the outbox, anything else (no network, a lost response) stays and
is sent again with the same id, which the server answers as the first time. A judgment is
checked before it is queued (a verdict, a new type that differs from the defect's); an item
the server refuses (a defect deleted meanwhile, a device clock far ahead, an outbox written
by an older client) is kept in ``refused`` with the reason until the user clears it, and
never holds back the rest. A verdict is lost only when the user clears it.

    vista-headset --url http://127.0.0.1:8000 --token DEVICE_TOKEN --inspection 1 \\
        --judge 12=confirmed --comment "burr on the edge" --judge 14=rejected --state headset.json
    vista-headset refused --state headset.json [--clear-refused]
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
DEFECT_TYPES = (
    "gap", "step", "parallelism", "mismatch", "scratch", "dent", "bump", "color", "deviation"
)  # fmt: skip
MAX_COMMENT_CHARS = 4000


class HeadsetOffline(ConnectionError):
    """The headset has no connection (``go_offline``), or the network failed."""


class StateMismatch(ValueError):
    """A state file of another inspection or server."""


@dataclass
class SyncReport:
    pages: int = 0
    defects: int = 0
    judgments: int = 0
    ended: int = 0
    """Findings the headset showed that a later measurement ended (superseded or not found
    again): they leave the shown list."""
    scene: str = "unchanged"
    """The scene since the sync before: ``first`` (no sync before), ``changed`` or ``unchanged``."""

    @property
    def scene_changed(self) -> bool:
        return self.scene == "changed"


@dataclass
class PushReport:
    sent: int = 0
    results: list[dict] = field(default_factory=list)
    refused: list[dict] = field(default_factory=list)
    """Items refused (malformed, or answered ``rejected``): kept in ``Headset.refused`` with
    the reason, not sent again."""

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
        """The current findings: what the headset shows and judges."""
        self.ended: dict[int, dict] = {}
        """Findings a later measurement ended (superseded: see ``superseded_by_id``; or not
        found again): history, not shown. A verdict queued for one still goes out and lands
        on its successor, or comes back refused with the reason."""
        self.judgments: dict[tuple[int, int], dict] = {}
        self.consensus: dict[int, dict] = {}
        self.scene_etag: str | None = None
        self.warnings: list[dict] = []
        """The inspection's succeeded jobs that could not do all they were asked (a
        measurement's unmeasured seams, and why), as the last sync listed them."""
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
        before = self.scene_etag
        while True:
            page = self._call(self.client.sync, self.inspection_id, self.cursor)
            report.pages += 1
            if page["inspection"] is not None:
                self.inspection = page["inspection"]
            for defect in page["defects"]:
                self._keep_defect(defect, report)
            for judgment in page["judgments"]:
                self._keep_judgment(judgment)
            for consensus in page["consensus"]:
                self.consensus[consensus["defect_id"]] = consensus
            report.defects += len(page["defects"])
            report.judgments += len(page["judgments"])
            self.scene_etag = page["scene_etag"]
            self.warnings = page.get("warnings", [])
            self.cursor = page["next_cursor"]
            if not page["more"]:
                break
        if before is None:
            report.scene = "first"
        elif self.scene_etag != before:
            report.scene = "changed"
        return report

    def _keep_defect(self, defect: dict, report: SyncReport) -> None:
        if defect.get("ended"):
            if self.defects.pop(defect["id"], None) is not None:
                report.ended += 1
            self.ended[defect["id"]] = defect
        else:
            self.defects[defect["id"]] = defect

    def successor_of(self, defect_id: int) -> int | None:
        """The current finding that continues ``defect_id`` (itself while current; None
        when a later measurement did not find it again, or the copy does not know)."""
        seen = set()
        while defect_id in self.ended and defect_id not in seen:
            seen.add(defect_id)
            defect_id = self.ended[defect_id].get("superseded_by_id")
            if defect_id is None:
                return None
        return defect_id if defect_id in self.defects else None

    def _keep_judgment(self, judgment: dict) -> None:
        self.judgments[(judgment["defect_id"], judgment["user_id"])] = judgment

    def judgment_of(self, defect_id: int, user_id: int) -> dict | None:
        """A user's judgment of a defect as the headset shows it: this user's latest queued
        edit while it waits in the outbox, else the server's copy."""
        if self.user is not None and user_id == self.user["id"]:
            queued = [
                item
                for item in self.outbox
                if defect_id in (item["defect_id"], self.successor_of(item["defect_id"]))
            ]
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
        if verdict == "reclassified" and self.defects[defect_id]["type"] == new_type:
            raise ValueError(
                f"defect {defect_id} already is a {new_type}; reclassify it as another type"
            )
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
        """Send the outbox; answered items leave it, items the server refuses (malformed, or
        answered ``rejected``) move to ``refused`` with the reason. Raises ``HeadsetOffline``
        when the connection fails (every unanswered item stays queued), ``VistaError`` when
        the server refuses the headset itself (401, 403)."""
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
        rejected = {
            r["client_id"]: r["detail"] for r in answer["results"] if r["status"] == "rejected"
        }
        self._set_aside(
            [(i, rejected[i["client_id"]]) for i in batch if i["client_id"] in rejected], report
        )
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

    def clear_refused(self) -> list[dict]:
        """Forget the refused items (the user has read them); returns what was cleared."""
        cleared, self.refused = self.refused, []
        return cleared

    # -- persistence ---------------------------------------------------------------------

    def save(self, path: Path) -> None:
        """Everything the headset knows, so it survives a restart while offline."""
        state = {
            "url": self.client.base_url,
            "inspection_id": self.inspection_id,
            "cursor": self.cursor,
            "inspection": self.inspection,
            "defects": list(self.defects.values()),
            "ended": list(self.ended.values()),
            "judgments": list(self.judgments.values()),
            "consensus": list(self.consensus.values()),
            "scene_etag": self.scene_etag,
            "loaded_scene_etag": self.loaded_scene_etag,
            "outbox": self.outbox,
            "refused": self.refused,
            "user": self.user,
        }
        _write_state(Path(path), state)

    @classmethod
    def load(
        cls, client: VistaClient, path: Path, inspection_id: int | None = None, **kwargs
    ) -> Headset:
        """The headset saved in ``path``. Raises ``StateMismatch`` when the file holds another
        inspection than ``inspection_id`` or another server than the client's."""
        state = json.loads(Path(path).read_text())
        if inspection_id is not None and state["inspection_id"] != inspection_id:
            raise StateMismatch(
                f"{path} holds inspection {state['inspection_id']}, not {inspection_id}: "
                "give each inspection its own --state file"
            )
        url = state.get("url")
        if url is not None and url != client.base_url:
            raise StateMismatch(f"{path} holds a copy from {url}, not from {client.base_url}")
        headset = cls(client, state["inspection_id"], **kwargs)
        headset.cursor = state["cursor"]
        headset.inspection = state["inspection"]
        headset.defects = {d["id"]: d for d in state["defects"]}
        headset.ended = {d["id"]: d for d in state.get("ended", [])}
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


class _Judge(argparse.Action):
    """``--judge D=VERDICT``: one judgment, with the ``--comment`` that follows it."""

    def __call__(self, parser, namespace, value, option_string=None) -> None:  # noqa: ANN001
        namespace.judge.append({"spec": value, "comment": ""})


class _Comment(argparse.Action):
    def __call__(self, parser, namespace, value, option_string=None) -> None:  # noqa: ANN001
        if not namespace.judge:
            parser.error("--comment follows the --judge it belongs to")
        namespace.judge[-1]["comment"] = value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="vista-headset",
        description="Sync one inspection like a headset: pull changes, queue judgments, push "
        "them. With --state the copy, the outbox and the refused judgments persist between "
        "runs (offline work). 'refused' lists the judgments the server refused.",
        epilog="Exit status: 0 everything queued or sent; 1 the server refused the headset, or "
        "judgments could not be sent and are not kept (no --state); 2 a judgment was refused.",
    )
    parser.add_argument(
        "command",
        nargs="?",
        choices=("sync", "refused"),
        default="sync",
        help="sync (the default): pull, queue, push; refused: list the refused judgments",
    )
    parser.add_argument("--url", help="the supervisor, e.g. http://host:8000 (sync)")
    parser.add_argument("--token", help="a device token, or any API token (sync)")
    parser.add_argument("--inspection", type=int, help="the inspection's id (sync)")
    parser.add_argument("--state", type=Path, help="JSON file with the headset's state")
    parser.add_argument(
        "--judge",
        action=_Judge,
        default=[],
        metavar="DEFECT=VERDICT",
        help="queue a judgment, e.g. 12=confirmed or 12=reclassified:dent (repeatable)",
    )
    parser.add_argument(
        "--comment", action=_Comment, metavar="TEXT", help="a comment on the --judge before it"
    )
    parser.add_argument("--offline", action="store_true", help="queue only; send nothing")
    parser.add_argument(
        "--clear-refused",
        action="store_true",
        help="forget the refused judgments after listing them (they are never sent)",
    )
    args = parser.parse_args(argv)
    if args.command == "refused":
        if args.state is None or not args.state.exists():
            parser.error("refused reads a headset's --state file")
        return _refused(args.state, clear=args.clear_refused)
    missing = [f"--{n}" for n in ("url", "token", "inspection") if getattr(args, n) is None]
    if missing:
        parser.error(f"sync needs {', '.join(missing)}")
    with VistaClient(args.url, args.token) as client:
        try:
            if args.state and args.state.exists():
                headset = Headset.load(client, args.state, args.inspection)
            else:
                headset = Headset(client, args.inspection)
        except StateMismatch as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        try:
            return _run(headset, args)
        except VistaError as exc:
            print(f"error: the server answered {exc.status}: {exc.detail}", file=sys.stderr)
            return 1
        finally:
            if args.state:
                headset.save(args.state)


def _run(headset: Headset, args: argparse.Namespace) -> int:
    online = not args.offline
    if online:
        try:
            pulled = headset.sync()
            scene = {"first": "first seen", "changed": "changed", "unchanged": "unchanged"}
            print(
                f"synced {pulled.defects} defects, {pulled.judgments} judgments "
                f"in {pulled.pages} page(s); scene {scene[pulled.scene]}"
                + (
                    f"; {pulled.ended} finding(s) measured again or not found again since "
                    "(their judgments travel on with the newer measurement)"
                    if pulled.ended
                    else ""
                )
            )
        except HeadsetOffline as exc:
            online = False
            print(f"server unreachable ({exc}): working from the local copy", file=sys.stderr)
    refused = 0
    for judge in args.judge:
        spec = judge["spec"]
        defect, _, verdict = spec.partition("=")
        verdict, _, new_type = verdict.partition(":")
        try:
            if not defect.strip().isdigit():
                raise ValueError(f"{defect!r} is not a defect id")
            item = headset.judge(
                int(defect), verdict, new_type=new_type or None, comment=judge["comment"]
            )
        except (ValueError, KeyError) as exc:
            print(f"not queued: --judge {spec}: {exc.args[0]}", file=sys.stderr)
            refused += 1
            continue
        print(f"queued: {_item_text(item)}")
    lost = False
    if online and headset.outbox:
        try:
            pushed = headset.push()
        except HeadsetOffline as exc:
            print(f"server unreachable ({exc})", file=sys.stderr)
        else:
            summary = {s: pushed.count(s) for s in ("applied", "unchanged", "stale")}
            print(f"pushed {pushed.sent}: {summary}, refused {len(pushed.refused)}")
            for item in pushed.refused:
                print(
                    f"  refused, kept in 'refused': {_item_text(item)}: {item['reason']}",
                    file=sys.stderr,
                )
            refused += len(pushed.refused)
    if headset.outbox:
        if args.state:
            print(f"{len(headset.outbox)} judgment(s) wait in {args.state} for the server")
        else:
            lost = True
            print(
                f"error: {len(headset.outbox)} judgment(s) not sent and not kept: "
                "give --state FILE so they wait for the server",
                file=sys.stderr,
            )
    if headset.refused and args.state:
        print(
            f"{len(headset.refused)} refused judgment(s) kept: vista-headset refused "
            f"--state {args.state}",
            file=sys.stderr,
        )
    return 1 if lost else 2 if refused else 0


def _refused(path: Path, *, clear: bool) -> int:
    state = json.loads(path.read_text())
    items = state.get("refused", [])
    for item in items:
        print(f"{_item_text(item)}: {item['reason']}")
    if not items:
        print("no refused judgments")
    if clear and items:
        state["refused"] = []
        _write_state(path, state)
        print(f"cleared {len(items)} refused judgment(s)")
    return 0


def _write_state(path: Path, state: dict) -> None:
    """Written aside, then moved over the old file: a crash leaves the old state whole."""
    temp = path.with_suffix(".tmp")
    temp.write_text(json.dumps(state))
    temp.replace(path)


def _item_text(item: dict) -> str:
    verdict = item.get("verdict")
    if item.get("new_type"):
        verdict = f"{verdict} as {item['new_type']}"
    comment = f" ({item['comment']!r})" if item.get("comment") else ""
    return f"defect {item.get('defect_id')} {verdict}{comment}"


if __name__ == "__main__":
    sys.exit(main())
