"""task_threads.run_split: a kernel's tasks in equal ranges, each task run once, side by side."""

import signal
import threading
import time

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


def test_a_forked_child_runs_its_ranges_on_threads_of_its_own():
    """The parent's threads do not exist in a forked child: the child makes its own."""
    import os

    if not hasattr(os, "fork"):
        pytest.skip("no fork on this platform")
    run_split(lambda first, last: None, 2, 2, ())  # the parent's pool exists
    pid = os.fork()
    if pid == 0:  # the child: exits 0 only if both ranges ran
        runs = np.zeros(4, int)
        try:
            run_split(lambda first, last: runs.__setitem__(slice(first, last), 1), 4, 2, ())
        finally:
            os._exit(0 if runs.all() else 1)
    deadline = time.monotonic() + 60.0  # a child waiting on threads it lacks never ends
    while (done := os.waitpid(pid, os.WNOHANG))[0] == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    if done[0] == 0:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        pytest.fail("the forked child's ranges never ran")
    assert os.waitstatus_to_exitcode(done[1]) == 0
