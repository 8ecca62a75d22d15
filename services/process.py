"""How a process that runs vista's algorithms is set up, once, where it starts (a job
worker, `vista measure`, a bench): ``prepare_process``.

BLAS runs one thread: the algorithms run their own threads (one per core they are given),
and BLAS threads on top of them would only fight them for the cores (and spin while they
wait).

A measurement's work arrays stay in the heap instead of fresh memory maps. glibc serves every allocation above 128 KB (its threshold grows to at most 32 MB) with its
own memory map and unmaps it when freed, so each height-map-sized temporary is faulted in
page by page again, and mapping and unmapping take a process-wide lock that the threads
measuring panels and seams all wait on: on 2 cores the panels ran no faster on two threads
than on one. Raising the threshold to 32 MB and trimming the heap only past 256 MB free
lets freed arrays be reused; the process keeps up to that much memory it no longer uses.
"""

from __future__ import annotations

import ctypes
import os
import sys
from functools import cache

from threadpoolctl import threadpool_limits

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20
"""glibc's largest allowed threshold on 64-bit systems."""
TRIM_THRESHOLD_BYTES = 256 << 20


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
    threadpool_limits(limits=1, user_api="blas")


def available_cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1
