"""Tasks shared by the calling thread and a pool's (`warpimpulse.pool.run_shared`)."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import pytest

from warpimpulse.pool import run_shared


def test_every_task_runs_once_and_the_results_keep_their_order():
    ran: list[int] = []
    with ThreadPoolExecutor(2) as pool:
        out = run_shared(pool, 2, [lambda i=i: ran.append(i) or i * i for i in range(50)])
    assert out == [i * i for i in range(50)] and sorted(ran) == list(range(50))
    with ThreadPoolExecutor(1) as pool:
        assert run_shared(pool, 0, [lambda: 1, lambda: 2]) == [1, 2] and run_shared(pool, 1, []) == []


def test_the_calling_thread_takes_the_task_of_a_pool_thread_that_does_not_come():
    """The pool's only thread is held up: the calling thread runs every task itself."""
    release = threading.Event()
    with ThreadPoolExecutor(1) as pool:
        pool.submit(release.wait)
        names = run_shared(pool, 1, [lambda: threading.current_thread().name for _ in range(3)])
        release.set()
    assert names == [threading.current_thread().name] * 3


def test_a_failing_task_raises_once_every_task_has_ended():
    ended: list[int] = []

    def task(i: int) -> None:
        if i == 1:
            raise ValueError("task 1 failed")
        ended.append(i)

    with ThreadPoolExecutor(1) as pool, pytest.raises(ValueError, match="task 1 failed"):
        run_shared(pool, 1, [lambda i=i: task(i) for i in range(4)])
    assert sorted(ended) == [0, 2, 3]
