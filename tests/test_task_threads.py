"""task_threads.run_split: a kernel's tasks in equal ranges, each task run once, side by side."""

import threading

import numpy as np
import pytest

from inertia_gym.task_threads import run_split


@pytest.mark.parametrize("tasks, threads", [(1, 4), (7, 1), (7, 2), (21, 2), (5, 8), (0, 2)])
def test_every_task_runs_once_in_ranges_of_equal_counts(tasks, threads):
    ranges, runs, names = [], np.zeros(max(tasks, 1), int), set()
    lock = threading.Lock()

    def kernel(first, last, out):
        with lock:
            ranges.append((first, last))
            names.add(threading.current_thread().name)
        out[first:last] += 1

    run_split(kernel, tasks, threads, (runs,))
    used = max(1, min(threads, tasks))
    assert len(ranges) == used and 1 <= len(names) <= used  # (at most the pool's threads and the caller)
    assert np.array_equal(runs[:tasks], np.ones(tasks, int))
    sizes = [last - first for first, last in ranges]
    assert max(sizes) - min(sizes) <= 1


def test_an_error_in_another_threads_range_reaches_the_caller():
    def kernel(first, last):
        if first > 0:
            raise ValueError("range failed")

    with pytest.raises(ValueError, match="range failed"):
        run_split(kernel, 4, 2, ())
