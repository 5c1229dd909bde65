"""Run independent tasks here (a process pool) or on a Ray cluster, one interface for both.

:func:`map_unordered` yields ``(task, result)`` pairs in completion order, so a caller can save
each result the moment it exists; the caller's code does not depend on the backend. A task sent to
a pool or a Ray worker runs with one numba, torch and BLAS thread (a worker per core is the
parallelism; more threads only oversubscribe the cores); with one worker or one task the
tasks run here, under the caller's own thread settings. :func:`kernels_own_the_cores` keeps
BLAS off the cores while numba's parallel kernels run in this process.
"""

from __future__ import annotations

import concurrent.futures as cf
import functools
import multiprocessing
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from threadpoolctl import threadpool_limits

from inertia_gym.errors import ConfigError

BACKENDS = ("local", "ray")


def single_threaded_worker() -> None:
    """Pin numba, torch and the BLAS and OpenMP libraries to one thread in this (worker) process."""
    import numba
    import torch

    numba.set_num_threads(1)
    torch.set_num_threads(1)
    threadpool_limits(1)


def kernels_own_the_cores(fn: Callable) -> Callable:
    """fn, run with BLAS (numpy's and scipy's OpenBLAS) held to one thread.

    For work that alternates numba's parallel kernels with small linear algebra (diagnose's
    fits): after each call OpenBLAS's idle workers spin for a while on the cores that the next
    kernel's threads need, and the kernel runs slower by a third (README, diagnose speed).
    Work whose BLAS calls are large gains from their threads instead (identify's sensitivities
    on a long record: it is not wrapped).
    """
    @functools.wraps(fn)
    def with_serial_blas(*args, **kwargs):
        with threadpool_limits(1, user_api="blas"):
            return fn(*args, **kwargs)
    return with_serial_blas


def _call_single_threaded(fn: Callable, task: Any) -> Any:
    single_threaded_worker()
    return fn(task)


def default_workers() -> int:
    """The number of cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def map_unordered(fn: Callable[[Any], Any], tasks: Iterable, *, backend: str = "local",
                  workers: int | None = None, ray_address: str | None = None
                  ) -> Iterator[tuple[Any, Any]]:
    """Apply `fn` to every task in parallel; yield (task, fn(task)) as each one finishes.

    backend : "local" runs `workers` processes here (default: one per core; 1 runs the tasks
        in this process, one after the other). "ray" sends each task to a Ray cluster as a
        one-CPU task: `ray_address` names an existing cluster ("auto", "HOST:PORT" or
        "ray://HOST:PORT"); None starts a local one with `workers` CPUs (default: the cores
        here) on the loopback interface, shut down afterwards. At most `workers` tasks are in
        flight (default: as many as the cluster takes). The cluster's nodes must have
        inertia-gym installed.
    fn and the tasks must be picklable (a module-level function, e.g. a functools.partial).
    An exception in a task is raised here; tasks not yet started are then cancelled. Bad
    arguments raise ConfigError at the call, before any task starts.
    """
    tasks = list(tasks)
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ConfigError(f"workers must be an integer >= 1, got {workers!r}")
    if ray_address is not None and backend != "ray":
        raise ConfigError("a Ray address needs backend 'ray'")
    if backend == "ray":
        return _map_ray(fn, tasks, workers, ray_address)
    return _map_local(fn, tasks, workers or default_workers())


def _map_local(fn, tasks, workers):
    if workers == 1 or len(tasks) <= 1:
        for task in tasks:
            yield task, fn(task)
        return
    # spawn: torch and numba keep threads that a forked child must not inherit.
    pool = cf.ProcessPoolExecutor(max_workers=min(workers, len(tasks)),
                                  mp_context=multiprocessing.get_context("spawn"),
                                  initializer=single_threaded_worker)
    try:
        futures = {pool.submit(fn, task): task for task in tasks}
        for future in cf.as_completed(futures):
            yield futures[future], future.result()
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


# Ray's switch for single-machine clusters (read when ray is first imported): a cluster started
# here keeps its traffic on the loopback interface instead of the machine's network address.
_RAY_SINGLE_MACHINE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _map_ray(fn, tasks, workers, address):
    if address is None and "ray" not in sys.modules:
        os.environ.setdefault(_RAY_SINGLE_MACHINE, "0")
    import ray

    started_here = not ray.is_initialized()
    if started_here:
        if address is None:
            ray.init(num_cpus=workers or default_workers(), include_dashboard=False,
                     log_to_driver=False, configure_logging=False)
        else:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(_call_single_threaded)
        queue = list(reversed(tasks))
        in_flight = workers or len(tasks)
        pending = {}
        try:
            while queue or pending:
                while queue and len(pending) < in_flight:
                    task = queue.pop()
                    pending[remote.remote(fn, task)] = task
                done, _ = ray.wait(list(pending), num_returns=1)
                task = pending.pop(done[0])
                yield task, ray.get(done[0])
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
    finally:
        if started_here:
            ray.shutdown()


__all__ = ["BACKENDS", "default_workers", "kernels_own_the_cores", "map_unordered", "single_threaded_worker"]
