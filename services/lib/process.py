"""How a process that runs vista's algorithms is set up, once, where it starts (a job
worker, `vista defects measure`, a bench): ``prepare_process``; and how a child process is tied
to its parent's life: ``die_with_parent``.

BLAS and OpenCV run one thread each: the algorithms run their own threads (one per core
they are given), and a library's threads on top of them would only fight them for the
cores, and spin while they wait. With OpenCV's own pool of two threads, odometry's frame
preparation (a divide, two pyramid levels) took 2.6 ms of CPU instead of 1.3, and a run on
two threads 4.6 ms per pair instead of 4.2.

That holds for a BLAS loaded after this set-up too. SciPy brings its own OpenBLAS, loaded
by the first ``from scipy import ndimage`` (in a job worker, when its first job's handler
is imported: after this set-up); numba's compiled ``np.dot`` and ``np.linalg.solve`` call
it. With its default thread per core, its second thread spun on a core after each such
call: a third of the CPU samples of a gap measurement were that thread waiting, and a
measurement on two threads ran 398 ms instead of 288 (issue 35).

A measurement's work arrays stay in the heap instead of fresh memory maps. glibc serves
every allocation above 128 KB (its threshold grows to at most 32 MB) with its own memory
map and unmaps it when freed, so each height-map-sized temporary is faulted in page by
page again, and mapping and unmapping take a process-wide lock that the threads measuring
panels and seams all wait on: on 2 cores the panels ran no faster on two threads than on
one. Raising the threshold to 32 MB and trimming the heap only past 256 MB free lets freed
arrays be reused; the process keeps up to that much memory it no longer uses.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys
from functools import cache

import cv2
from threadpoolctl import threadpool_limits

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20
"""glibc's largest allowed threshold on 64-bit systems."""
TRIM_THRESHOLD_BYTES = 256 << 20
PR_SET_PDEATHSIG = 1


@cache
def keep_work_arrays_in_heap() -> bool:
    """Tune glibc's allocator as above (once per process); False where there is no glibc
    (nothing changes there)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )


@cache
def prepare_process() -> None:
    """Tune this process for vista's algorithms (see the module docstring); once."""
    keep_work_arrays_in_heap()
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # each OpenBLAS loaded later (children too)
    threadpool_limits(limits=1, user_api="blas")  # and those already loaded
    cv2.setNumThreads(1)


def physical_memory_mb() -> int:
    """This machine's memory, MiB."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") >> 20


def default_job_memory_mb() -> int:
    """Three quarters of the machine's memory, and at least 8 GiB (an address space holds
    more than the memory in use: the libraries' reservations, each thread's stack)."""
    return max(physical_memory_mb() * 3 // 4, 8192)


def limit_address_space(memory_mb: int) -> None:
    """Cap this process's address space (RLIMIT_AS): an allocation beyond it raises
    MemoryError where it happens, instead of the kernel's OOM killer taking the whole
    process (and a job it ran being retried to meet the same end)."""
    import resource

    limit = memory_mb << 20
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def available_cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def die_with_parent(parent_pid: int) -> None:
    """Linux: SIGTERM this process when its parent dies, even by SIGKILL, so a child of a
    killed server (an API process, a job worker) never lives on as an orphan taking work
    beside the restarted server's own children.

    ``parent_pid`` is the parent's pid as the parent saw it when starting this process:
    the signal is only armed from here on, so a parent that died before this call is
    caught by comparing it with ``os.getppid()`` (then this process stops at once). The
    kernel sends the signal when the *thread* that started this process ends, so start
    children from a thread that outlives them."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):  # not Linux: the parent's own shutdown still stops it
        pass
    if not parent_alive(parent_pid):
        os.kill(os.getpid(), signal.SIGTERM)


def parent_alive(parent_pid: int) -> bool:
    """Whether this process's parent is still ``parent_pid`` (an orphan is adopted by
    another process, usually PID 1), for loops that should end with their parent even
    where the death signal is missing."""
    return os.getppid() == parent_pid
