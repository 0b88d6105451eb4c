"""Independent tasks shared by the calling thread and a pool's threads (`threads.py`, `split.py`).

Each thread takes the next task nobody has taken yet. A pool thread that a busy machine is slow to wake then
leaves its task to the calling thread instead of holding everything up, and the calling thread does work
instead of waiting. A task runs once, on whichever thread took it: the tasks must not depend on each other.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor


def run_shared(pool: ThreadPoolExecutor, helpers: int, tasks: Sequence[Callable[[], object]]) -> list:
    """Every task's result, in order, the tasks run by this thread and up to `helpers` of the pool's; the first
    exception a task raised, once every task has ended."""
    count = len(tasks)
    results: list = [None] * count
    if count == 0:
        return results
    claims = itertools.count()
    finished, lock, done = [0], threading.Lock(), threading.Event()
    failures: list[BaseException] = []

    def work() -> None:
        while (i := next(claims)) < count:
            try:
                results[i] = tasks[i]()
            except BaseException as exc:  # raised by the calling thread once every task has ended
                failures.append(exc)
            with lock:
                finished[0] += 1
                if finished[0] == count:
                    done.set()

    for _ in range(min(helpers, count - 1)):
        pool.submit(work)
    work()
    done.wait()
    if failures:
        raise failures[0]
    return results
