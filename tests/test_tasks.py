"""The map in which the calling thread helps its pool (services.lib.tasks)."""

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from services.lib.tasks import helping_map, start_helping


def test_without_a_pool_the_caller_runs_every_task_largest_first_results_in_order():
    ran = []

    def task(name: str) -> str:
        ran.append(name)
        return name.upper()

    result = helping_map(None, task, ["a", "b", "c"], sizes=[1, 3, 2])
    assert result == ["A", "B", "C"]
    assert ran == ["b", "c", "a"]


def test_the_caller_works_while_the_pool_is_busy_and_the_pool_joins_once_free():
    """A pool thread held by earlier work: the caller starts the tasks at once; when the
    earlier work ends, the pool's thread takes tasks too."""
    release = threading.Event()
    workers: dict[str, str] = {}

    def task(name: str) -> str:
        if name == "first":
            release.set()  # the pool's thread is free from now on
        time.sleep(0.05)
        workers[name] = threading.current_thread().name
        return name

    names = ["first", *(f"t{i}" for i in range(7))]
    with ThreadPoolExecutor(1, thread_name_prefix="pool") as pool:
        pool.submit(release.wait)  # earlier work, until the caller has started
        assert helping_map(pool, task, names, helpers=1) == names
    assert workers["first"] == threading.current_thread().name
    assert any(name.startswith("pool") for name in workers.values())


def test_a_failing_task_raises_in_the_caller_after_the_others_ended():
    ended = []

    def task(value: int) -> int:
        if value == 2:
            raise ValueError("task 2 failed")
        time.sleep(0.01)
        ended.append(value)
        return value

    with (
        ThreadPoolExecutor(2) as pool,
        pytest.raises(ValueError, match="task 2 failed"),
    ):
        helping_map(pool, task, range(6), helpers=2)
    assert sorted(ended) == [0, 1, 3, 4, 5]


def test_started_tasks_run_on_the_pool_while_the_caller_is_busy_and_it_takes_the_rest():
    """The pool's thread starts at once, largest first; the caller, busy with its own work
    meanwhile, takes what is left when it finishes; results in the arguments' order."""
    pool_started = threading.Event()
    caller_free = threading.Event()
    workers: dict[int, str] = {}

    def task(size: int) -> int:
        if threading.current_thread().name.startswith("pool"):
            pool_started.set()
            caller_free.wait(5)  # held until the caller has joined
        else:
            caller_free.set()
        workers[size] = threading.current_thread().name
        return size * 10

    with ThreadPoolExecutor(1, thread_name_prefix="pool") as pool:
        work = start_helping(pool, task, [1, 4, 2, 3], sizes=[1, 4, 2, 3], helpers=1)
        assert pool_started.wait(5)  # before the caller joins
        assert work.finish() == [10, 40, 20, 30]
    assert workers[4].startswith("pool")  # the largest, taken first by the pool
    assert {workers[s] for s in (1, 2, 3)} == {threading.current_thread().name}
