"""A map over a thread pool in which the calling thread works too, largest task first.

``Executor.map`` queues its tasks behind every task submitted before them, and the caller
only waits: a measurement that submits its surface work first and its seams after finds
its seams' last task alone on one core while the other idles. Here the tasks of one map
form their own list; the caller and, as soon as they are free, the pool's threads take the
next task from it, the largest first (by the size the caller gives), so the last to finish
is a small one.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor
from typing import Any


class _Tasks:
    """Tasks taken in turn by whichever thread asks next; each result (or exception) kept."""

    def __init__(self, fn: Callable, arguments: Sequence[tuple], order: list[int]) -> None:
        self._fn, self._arguments, self._order = fn, arguments, order
        self._lock = threading.Lock()
        self._next = 0
        self._done = threading.Semaphore(0)
        self.results: list[Any] = [None] * len(arguments)
        self.errors: list[BaseException | None] = [None] * len(arguments)

    def drain(self) -> None:
        """Run tasks until none is left to take."""
        while True:
            with self._lock:
                if self._next == len(self._order):
                    return
                index = self._order[self._next]
                self._next += 1
            try:
                self.results[index] = self._fn(*self._arguments[index])
            except BaseException as error:  # handed to the caller, raised there
                self.errors[index] = error
            finally:
                self._done.release()

    def wait(self) -> list[Any]:
        for _ in self._arguments:
            self._done.acquire()
        for error in self.errors:
            if error is not None:
                raise error
        return self.results


def helping_map(
    pool: Executor | None,
    fn: Callable,
    *iterables: Iterable,
    sizes: Sequence[float] | None = None,
    helpers: int = 1,
) -> list[Any]:
    """``[fn(*args) for args in zip(*iterables)]``, run by the calling thread and by up to
    ``helpers`` of ``pool``'s threads (each joins when it is free), tasks taken largest
    ``sizes`` first (in order without); results in the arguments' order. The first
    exception of a task is raised once all have ended. Without a pool: in this thread."""
    arguments = list(zip(*iterables, strict=True))
    order = sorted(range(len(arguments)), key=lambda i: -sizes[i]) if sizes else None
    tasks = _Tasks(fn, arguments, order or list(range(len(arguments))))
    if pool is not None:
        for _ in range(min(helpers, max(len(arguments) - 1, 0))):
            pool.submit(tasks.drain)
    tasks.drain()
    return tasks.wait()
