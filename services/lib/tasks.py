"""A map over a thread pool in which the calling thread works too, largest task first.

``Executor.map`` queues its tasks behind every task submitted before them, and the caller
only waits: a measurement that submits its surface work first and its seams after finds
its seams' last task alone on one core while the other idles. Here the tasks of one map
form their own list; the caller and, as soon as they are free, the pool's threads take the
next task from it, the largest first (by the size the caller gives), so the last to finish
is a small one. ``start_helping`` lets the caller do other work before it joins: the
pool's threads start on the tasks at once.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor
from typing import Any


class Helping:
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

    def finish(self) -> list[Any]:
        """Run the tasks not yet taken in this thread, wait for the rest; the results in
        the arguments' order, or the first task's exception once all have ended."""
        self.drain()
        for _ in self._arguments:
            self._done.acquire()
        for error in self.errors:
            if error is not None:
                raise error
        return self.results


def start_helping(
    pool: Executor | None,
    fn: Callable,
    *iterables: Iterable,
    sizes: Sequence[float] | None = None,
    helpers: int = 1,
) -> Helping:
    """The tasks ``fn(*args) for args in zip(*iterables)``, taken largest ``sizes`` first (in
    order without) by up to ``helpers`` of ``pool``'s threads as soon as each is free; the
    caller joins them with ``finish()``, which returns the results in the arguments'
    order. Without a pool, ``finish()`` runs them all."""
    return _start(pool, fn, list(zip(*iterables, strict=True)), sizes, helpers)


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
    helpers = min(helpers, max(len(arguments) - 1, 0))  # the caller takes one
    return _start(pool, fn, arguments, sizes, helpers).finish()


def _start(
    pool: Executor | None,
    fn: Callable,
    arguments: list[tuple],
    sizes: Sequence[float] | None,
    helpers: int,
) -> Helping:
    order = sorted(range(len(arguments)), key=lambda i: -sizes[i]) if sizes else None
    tasks = Helping(fn, arguments, order or list(range(len(arguments))))
    if pool is not None:
        for _ in range(min(helpers, len(arguments))):
            pool.submit(tasks.drain)
    return tasks
