"""Keep a measurement's work arrays in the heap instead of fresh memory maps.

glibc serves every allocation above 128 KB (its threshold grows to at most 32 MB) with its
own memory map and unmaps it when freed, so each height-map-sized temporary is faulted in
page by page again, and mapping and unmapping take a process-wide lock that the threads
measuring panels and seams all wait on: on 2 cores the panels ran no faster on two threads
than on one. Raising the threshold to 32 MB and trimming the heap only past 256 MB free
lets freed arrays be reused; the process keeps up to that much memory it no longer uses.
"""

from __future__ import annotations

import ctypes
import sys
from functools import cache

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
