"""A scanner's cloud converted in a child process held to limits: ``convert_isolated``.

The format libraries run in a fresh interpreter (``python -m
services.lib.pointcloud.reader``), so one that crashes on a damaged file (lazrs aborts on
some) or loops takes only the child. The child is held to ``ReaderLimits``: its address
space beyond what its libraries hold once loaded (RLIMIT_AS set to that plus the limit, so
the limit means the same on hosts whose libraries reserve more or less: an allocation beyond
it fails as MemoryError, reported as such), its CPU
seconds (RLIMIT_CPU: SIGXCPU ends it), and at most ``at_once`` of them run on a host (a
lock file per slot; an upload beyond them is answered 429). It dies with the thread that
started it (PR_SET_PDEATHSIG: a killed server leaves no reader behind), is killed with its
process group when the caller cancels (a client that went away), and a refused or failed
conversion leaves no output.
"""

from __future__ import annotations

import contextlib
import contextvars
import fcntl
import json
import os
import resource
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from services.lib.pointcloud.promises import ReaderLimits
from services.lib.pointcloud.scanner import FORMAT_NAMES, ScannerFormatError, sniff

WALL_PER_CPU = 3
"""The child's wall-clock limit, in multiples of its CPU limit (it waits on the disk too)."""
POLL_S = 0.1
RETRY_AFTER_S = 10
CANCELLED: contextvars.ContextVar[threading.Event | None] = contextvars.ContextVar(
    "reader_cancelled", default=None
)
"""Set by a caller whose reason to read may go away (a request whose client may
disconnect): the reader is killed when the event is set."""


@dataclass(frozen=True)
class ReaderUsage:
    cpu_s: float
    peak_mb: float
    """The child's largest resident set since it started its interpreter (its VmHWM;
    NaN if it did not answer: ru_maxrss would count the server it was forked from)."""


USAGE: contextvars.ContextVar[list[ReaderUsage] | None] = contextvars.ContextVar(
    "reader_usage", default=None
)
"""Set to a list to collect what each reader run in this context used (the fuzz tests)."""


class ReadersBusy(RuntimeError):
    """Every reader slot of this host is taken; try again after ``retry_after_s``."""

    def __init__(self, at_once: int) -> None:
        super().__init__(
            f"{at_once} cloud conversions are running on this server, its limit "
            "(VISTA_READERS_AT_ONCE); send the file again shortly"
        )
        self.retry_after_s = RETRY_AFTER_S


def slot_dir() -> Path:
    """The lock files that count this host's readers: ``VISTA_READER_SLOTS_DIR``, else one
    folder per user in the temporary directory (every vista process of the user shares it)."""
    given = os.environ.get("VISTA_READER_SLOTS_DIR")
    folder = Path(given) if given else Path(tempfile.gettempdir()) / f"vista-readers-{os.getuid()}"
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    return folder


@contextlib.contextmanager
def reader_slot(at_once: int) -> Iterator[int]:
    """One of ``at_once`` slots held for the block (an exclusive lock on its file, which
    the kernel drops if this process dies); ``ReadersBusy`` if all are held."""
    folder = slot_dir()
    for index in range(at_once):
        handle = open(folder / f"slot-{index}.lock", "a+b")  # noqa: SIM115
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            continue
        try:
            yield index
        finally:
            handle.close()
        return
    raise ReadersBusy(at_once)


def convert_isolated(
    path: Path, out: Path, *, units: str | None = None, limits: ReaderLimits | None = None
) -> dict:
    """``path`` converted to vista's PLY at ``out`` in a limited child process; returns
    ``Converted.meta()``. Raises ``ScannerFormatError`` naming what went wrong (nothing
    left at ``out``), ``ReadersBusy`` when the host's readers are all taken."""
    limits = limits or ReaderLimits.from_env()
    cancelled = CANCELLED.get() or threading.Event()
    with reader_slot(limits.at_once):
        try:
            answer, code = _run_child(path, out, units, limits, cancelled)
        except BaseException:
            out.unlink(missing_ok=True)
            raise
    if answer is None or "error" in answer:
        out.unlink(missing_ok=True)
    if answer is None:
        fmt = FORMAT_NAMES.get((sniff(path) if path.is_file() else None) or "", "cloud")
        raise ScannerFormatError(f"is not a readable {fmt} file: {_why(code, limits)}")
    if "error" in answer:
        raise ScannerFormatError(answer["error"])
    return answer["meta"]


def _run_child(
    path: Path, out: Path, units: str | None, limits: ReaderLimits, cancelled: threading.Event
) -> tuple[dict | None, int | str]:
    """The child's answer (None if it gave none) and its exit code, or why it was ended;
    what it used is added to ``USAGE``'s list, if one is set."""
    env = {
        **os.environ,
        "VISTA_MAX_CLOUD_POINTS": str(limits.max_points),
        "VISTA_READER_MEMORY_MB": str(limits.memory_mb),
        "VISTA_READER_CPU_S": str(limits.cpu_s),
    }
    child = subprocess.Popen(
        _command(path, out, units),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
        env=env,
        start_new_session=True,
    )
    deadline = time.monotonic() + WALL_PER_CPU * limits.cpu_s
    ended: str | None = None
    try:
        output = _answer(child, cancelled, deadline)
        if output is None:
            ended = "cancelled" if cancelled.is_set() else "wall"
        status, usage = _reap(child)
    finally:
        if child.returncode is None:  # an exception while waiting: no child left behind
            _kill(child)
            _reap(child)
        child.stdout.close()  # type: ignore[union-attr]
    try:
        answer = None if ended else json.loads(output.decode())  # type: ignore[union-attr]
    except ValueError:
        answer = None
    if (log := USAGE.get()) is not None:
        peak = (answer or {}).get("peak_mb", float("nan"))
        log.append(ReaderUsage(usage.ru_utime + usage.ru_stime, peak))
    return answer, ended or status


def _command(path: Path, out: Path, units: str | None) -> list[str]:
    module = "services.lib.pointcloud.reader"
    return [sys.executable, "-m", module, str(path), str(out), units or "", str(os.getpid())]


def _answer(child: subprocess.Popen, cancelled: threading.Event, deadline: float) -> bytes | None:
    """What the child printed once its output closes (it exits), or None once it was
    killed: the caller cancelled or the deadline passed."""
    chunks = []
    stream = child.stdout
    os.set_blocking(stream.fileno(), False)  # type: ignore[union-attr]
    while True:
        ready, _, _ = select.select([stream], [], [], POLL_S)
        if ready:
            chunk = stream.read()  # type: ignore[union-attr]
            if chunk == b"":
                return b"".join(chunks)
            chunks.append(chunk or b"")
        if cancelled.is_set() or time.monotonic() > deadline:
            _kill(child)
            return None


def _kill(child: subprocess.Popen) -> None:
    """SIGKILL the child's process group (the child and anything it started)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(child.pid, signal.SIGKILL)


def _reap(child: subprocess.Popen) -> tuple[int, resource.struct_rusage]:
    """Wait for the child; its exit code (negative: the signal) and what it used."""
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    return child.returncode, usage


def _why(code: int | str, limits: ReaderLimits) -> str:
    if code == "cancelled":
        return "the upload was abandoned while it was read"
    if code == "wall":
        return f"it took longer than {WALL_PER_CPU * limits.cpu_s} s to read"
    if code in (-signal.SIGXCPU, -signal.SIGKILL):  # the soft CPU limit, then the hard one
        return f"it took more than {limits.cpu_s} s of CPU to read (VISTA_READER_CPU_S)"
    return f"its reader crashed on it ({f'signal {-code}' if code < 0 else f'exit {code}'})"


def _child(path: Path, out: Path, units: str | None, parent_pid: int) -> dict:
    """In the child: limits set, the file read and written; the answer to print."""
    from services.lib.pointcloud.ply import write_ply
    from services.lib.pointcloud.scanner import read_cloud
    from services.lib.process import die_with_parent

    die_with_parent(parent_pid)
    limits = ReaderLimits.from_env()
    memory = _address_space_bytes() + (limits.memory_mb << 20)
    resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    resource.setrlimit(resource.RLIMIT_CPU, (limits.cpu_s, limits.cpu_s + 5))
    try:
        converted = read_cloud(path, units=units, limits=limits)
        write_ply(out, converted.cloud)
    except ScannerFormatError as exc:
        return {"error": str(exc)}
    except MemoryError:
        return {
            "error": f"needs more memory to read than a reader may take ({limits.memory_mb} MiB, "
            "VISTA_READER_MEMORY_MB)"
        }
    return {"meta": converted.meta()}


def _address_space_bytes() -> int:
    """This process's address space now (VmSize), bytes."""
    return int(_status_kb("VmSize") * 1024)


def _status_kb(field: str) -> float:
    status = Path("/proc/self/status").read_text().split(f"{field}:")
    return int(status[1].split()[0]) if len(status) > 1 else float("nan")


def _peak_mb() -> float:
    """This process's largest resident set (VmHWM), MiB."""
    return _status_kb("VmHWM") / 1024


if __name__ == "__main__":
    source, target, unit, parent = sys.argv[1:5]
    answer = _child(Path(source), Path(target), unit or None, int(parent))
    answer["peak_mb"] = _peak_mb()
    sys.stdout.write(json.dumps(answer))
    sys.stdout.flush()
    os._exit(0)  # no interpreter teardown: the answer is out, the limits may bite on exit
