"""Run independent tasks here (a process pool) or on a Ray cluster, one interface for both.

:func:`map_unordered` yields ``(task, result)`` pairs in completion order, so a caller can save
each result the moment it exists; the caller's code does not depend on the backend. A task sent to
a pool or a Ray worker runs with one numba, torch and BLAS thread (a worker per core is the
parallelism; more threads only oversubscribe the cores); with one worker or one task the
tasks run here, under the caller's own thread settings. :func:`kernels_own_the_cores` keeps
BLAS off the cores while numba's parallel kernels run in this process.

:func:`fan_out` is for the independent pieces of one job (diagnose's candidate fits): this
process takes them one after the other and helper processes take them too, results in task
order, the same as run here. The helpers (one per other core, at most MAX_HELPERS) start on
first use and live as long as this process; a task goes to one only once it has started.
Never inside a pool worker or a helper (those already fill the cores), and never with
HELPERS_VARIABLE=0.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import functools
import importlib
import multiprocessing
import multiprocessing.connection
import os
import signal
import sys
import threading
import time
import types
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from threadpoolctl import threadpool_limits

from inertia_gym.errors import ConfigError, install_hint

BACKENDS = ("local", "ray")
_HOME = os.getpid()  # the process that imported this module
_MISSING = object()  # a result not (yet) in
#: environment variable: "0" runs fan_out's tasks in the calling process only (also set in every
#: worker and helper, so that they never start helpers of their own)
HELPERS_VARIABLE = "INERTIA_GYM_HELPERS"
#: at most this many helpers: a fan-out holds a handful of tasks (diagnose's: 3 to 14), and each
#: helper holds its own copy of the package in memory
MAX_HELPERS = 3


def single_threaded_worker() -> None:
    """Pin numba, torch and the BLAS and OpenMP libraries to one thread in this (worker) process."""
    import numba
    import torch

    os.environ[HELPERS_VARIABLE] = "0"
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    threadpool_limits(1)


def kernels_own_the_cores(fn: Callable) -> Callable:
    """fn, run with BLAS (numpy's and scipy's OpenBLAS) held to one thread.

    For work that alternates numba's parallel kernels with small linear algebra (diagnose's
    fits): after each call OpenBLAS's idle workers spin for a while on the cores that the next
    kernel's threads need, and the kernel runs slower by a third (docs/results.md, speed).
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


def _helper_started() -> None:
    """A helper's initializer: one numba and BLAS thread (torch is not needed: not imported),
    no helpers of its own, Ctrl-C left to the process that started it (which stops the
    helpers), and a watch on that process: a helper whose parent died (it never said stop)
    ends itself instead of waiting for tasks forever.
    """
    import numba

    os.environ[HELPERS_VARIABLE] = "0"
    numba.set_num_threads(1)
    threadpool_limits(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = multiprocessing.parent_process()

    def watch() -> None:
        multiprocessing.connection.wait([parent.sentinel])  # returns when the parent is gone
        os._exit(0)

    if parent is not None:
        threading.Thread(target=watch, daemon=True).start()


def _imported(module: str) -> None:
    """Import `module` here (a helper's first task: the modules its tasks need, loaded before it
    counts as started).
    """
    importlib.import_module(module)


@contextlib.contextmanager
def _main_module_hidden():
    """A spawned child re-runs the parent's main script (as __mp_main__) unless it is a
    package's __main__; a user's script that calls diagnose at its top level would then run
    again in every helper. Helpers need only the package: the main module is hidden while they
    start.
    """
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


class _Helpers:
    """The process's helper pool (spawned: torch and numba keep threads that a forked child
    must not inherit), created on first use; `ready` once its processes have started. A pool
    that breaks (a helper killed) is not used again: the tasks run here. Only the process that
    imported this module, and not one that multiprocessing started, has helpers: a forked child
    would share its parent's pool, a pool worker may not start processes (a daemon), and a
    multiprocessing child joins its own children before anything tells them to stop.
    """

    pool: cf.ProcessPoolExecutor | None = None
    started: list = []
    count = 0
    broken = False
    sent = 0  # tasks sent to the helpers so far
    lock = threading.Lock()

    @classmethod
    def ready(cls, module: str) -> int:
        """Helpers that can take a task now (0 while they start and import `module`, or where
        there are none).
        """
        if (cls.broken or os.environ.get(HELPERS_VARIABLE) == "0" or default_workers() < 2
                or os.getpid() != _HOME or multiprocessing.parent_process() is not None):
            return 0
        with cls.lock:
            if cls.pool is None:
                cls.count = min(default_workers() - 1, MAX_HELPERS)
                try:
                    cls.pool = cf.ProcessPoolExecutor(max_workers=cls.count,
                                                      mp_context=multiprocessing.get_context("spawn"),
                                                      initializer=_helper_started)
                    with _main_module_hidden():  # the pool starts its processes as tasks arrive
                        cls.started = [cls.pool.submit(_imported, module) for _ in range(cls.count)]
                except (OSError, RuntimeError):  # no processes here: the tasks run here
                    cls.broken = True
                    return 0
        if not all(f.done() for f in cls.started):
            return 0
        if any(f.exception() is not None for f in cls.started):
            cls.broken = True
            return 0
        return cls.count


def helpers_ready(module: str) -> int:
    """The helpers fan_out would use now for tasks of `module` (starting them where they would
    be used: 0 until they have started).
    """
    return _Helpers.ready(module)


def wait_for_helpers(module: str, timeout: float = 120.0) -> int:
    """Start the helpers (where fan_out would use them) and wait until they have imported
    `module`: the number of helpers then (0 where there are none, or after `timeout` s).
    fan_out never waits for them; a benchmark or a test that wants them running does.
    """
    deadline = time.monotonic() + timeout
    while not (count := _Helpers.ready(module)) and time.monotonic() < deadline:
        if _Helpers.broken or _Helpers.pool is None:
            return 0
        time.sleep(0.05)
    return count


def fan_out(fn: Callable[[Any], Any], tasks: Iterable) -> list:
    """[fn(task) for task in tasks], with the helpers (one per other core, at most MAX_HELPERS)
    taking tasks beside this process once they have started. fn and the tasks must be picklable,
    fn from an importable module (not the main script: hidden from the helpers), and fn(task)
    must depend on the task alone and on nothing this process changed at run time (so that
    where it runs changes nothing). While helpers run, this process's numba kernels keep to one
    thread. A task's exception is raised here (that of the first such task in order), after
    the tasks already sent have finished; a task whose helper failed (not the task) runs here.
    """
    tasks = list(tasks)
    helpers = _Helpers.ready(getattr(fn, "func", fn).__module__) if len(tasks) > 1 else 0
    if not helpers:
        return [fn(task) for task in tasks]
    import numba

    results: list = [_MISSING] * len(tasks)
    errors: dict = {}  # task index -> its exception
    lock = threading.Lock()
    order = list(range(len(tasks)))[::-1]  # popped from the end: first task first

    def take() -> int | None:
        with lock:
            return order.pop() if order and not errors else None

    def hand_back(i: int) -> None:
        with lock:
            order.append(i)

    def feed() -> None:  # keeps every helper busy while tasks are left
        running: set = set()
        try:
            while True:
                while not _Helpers.broken and len(running) < helpers and (i := take()) is not None:
                    try:
                        future = _Helpers.pool.submit(fn, tasks[i])
                    except (cf.BrokenExecutor, RuntimeError):
                        _Helpers.broken = True
                        hand_back(i)
                        break
                    _Helpers.sent += 1
                    future.index = i
                    running.add(future)
                if not running:
                    return
                done, running = cf.wait(running, return_when=cf.FIRST_COMPLETED)
                for future in done:
                    error = None if future.cancelled() else future.exception()
                    if future.cancelled() or isinstance(error, cf.BrokenExecutor):
                        _Helpers.broken = True
                        hand_back(future.index)  # run here instead
                    elif error is not None:
                        with lock:
                            errors[future.index] = error
                    else:
                        results[future.index] = future.result()
        except BaseException:  # the helpers failed in a way not foreseen: their tasks run here
            _Helpers.broken = True
            for future in running:
                hand_back(future.index)

    feeder = threading.Thread(target=feed, daemon=True)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        feeder.start()
        while True:
            i = take()
            if i is None:
                feeder.join(0.01)
                if feeder.is_alive() and not errors:
                    continue  # a broken helper may hand its task back
                with lock:
                    if not order or errors:
                        break
                continue
            try:
                results[i] = fn(tasks[i])
            except Exception as error:
                with lock:
                    errors[i] = error
    except BaseException:  # (Ctrl-C here: nothing more is sent; the tasks running finish)
        with lock:
            order.clear()
        raise
    finally:
        numba.set_num_threads(threads)
        if feeder.is_alive():
            feeder.join()
    if errors:
        raise errors[min(errors)]
    if any(r is _MISSING for r in results):  # (cannot happen: every task ran here or in a helper)
        raise RuntimeError("fan_out lost a task's result")
    return results


# Ray's switch for single-machine clusters (read when ray is first imported): a cluster started
# here keeps its traffic on the loopback interface instead of the machine's network address.
_RAY_SINGLE_MACHINE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _map_ray(fn, tasks, workers, address):
    if address is None and "ray" not in sys.modules:
        os.environ.setdefault(_RAY_SINGLE_MACHINE, "0")
    try:
        import ray
    except ImportError as exc:
        raise ConfigError(f"the Ray backend needs Ray, an optional extra: {install_hint('ray')}") from exc

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


__all__ = ["BACKENDS", "HELPERS_VARIABLE", "default_workers", "fan_out", "kernels_own_the_cores",
           "helpers_ready", "map_unordered", "single_threaded_worker", "wait_for_helpers"]
