"""A compiled kernel's tasks run side by side on threads.

A batched kernel (model_dynamics.py's integrator) is a serial numba function that releases the
GIL and takes a range of tasks (first, last): :func:`run_split` hands equal ranges to threads,
the caller's among them. A serial kernel compiles in about 60 % of the time of numba's
parallel one, and a batch too small to share runs in one call, without the threading layer's
launch.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba as nb

_POOL: list = []  # the threads, made on first use
_POOL_LOCK = threading.Lock()


def _forget_after_fork() -> None:
    """A forked child starts without the parent's threads (and with its lock free)."""
    global _POOL_LOCK
    _POOL_LOCK = threading.Lock()
    _POOL.clear()


os.register_at_fork(after_in_child=_forget_after_fork)


def _pool() -> ThreadPoolExecutor:
    with _POOL_LOCK:
        if not _POOL:
            _POOL.append(ThreadPoolExecutor(max(1, nb.config.NUMBA_NUM_THREADS - 1),
                                            thread_name_prefix="inertia-gym-tasks"))
        return _POOL[0]


def run_split(kernel, tasks: int, threads: int, args: tuple) -> None:
    """kernel(first, last, *args) over the tasks 0 .. tasks - 1, in `threads` ranges of equal
    task counts run side by side (one call where threads <= 1). The kernel must release the GIL
    and write only what its own tasks own.
    """
    threads = max(1, min(threads, tasks))
    if threads == 1:
        kernel(0, tasks, *args)
        return
    bounds = [tasks * k // threads for k in range(threads + 1)]
    others = [_pool().submit(kernel, bounds[k], bounds[k + 1], *args) for k in range(1, threads)]
    kernel(bounds[0], bounds[1], *args)
    for future in others:
        future.result()
