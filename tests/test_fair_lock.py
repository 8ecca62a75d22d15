"""SQLite's writers queue on a lock granted in the order it was asked for."""

from __future__ import annotations

import threading
import time

from supervisor.db import FairLock


def test_waiters_get_the_lock_in_the_order_they_asked() -> None:
    lock = FairLock()
    lock.acquire()
    order: list[int] = []

    def writer(k: int) -> None:
        lock.acquire()
        order.append(k)
        time.sleep(0.001)  # holding it while the others keep waiting
        lock.release()

    threads = []
    for k in range(12):
        thread = threading.Thread(target=writer, args=(k,))
        thread.start()
        threads.append(thread)
        deadline = time.monotonic() + 5
        while len(lock._waiters) < k + 1 and time.monotonic() < deadline:
            time.sleep(0.0005)  # k is queued before k + 1 asks
    lock.release()
    for thread in threads:
        thread.join(5)
    assert order == list(range(12))
    lock.acquire()  # free again: taken at once
    lock.release()
    assert not lock._held and not lock._waiters
