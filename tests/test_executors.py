"""The thread budget of the compiled work: BLAS held to one thread while diagnose's kernels run
and in every pool worker; the caller's own limits restored afterwards, also after an error.
And fan_out's helper processes: tasks shared, order kept, errors raised, a dead helper's task
run here, a user's unguarded script not run again, diagnose's report unchanged."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from inertia_gym import executors
from inertia_gym.discrepancy import report
from inertia_gym.discrepancy.effects import REGISTRY, GyroBias
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.executors import kernels_own_the_cores, map_unordered
from inertia_gym.scenario import Scenario


def blas_threads(_task=None) -> list[int]:
    """Threads of every BLAS library loaded in this process."""
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


class Seen(Exception):
    """Raised by a probe once it has looked at the thread budget."""


@pytest.fixture
def two_blas_threads():
    """BLAS allowed two threads around the test (a one-core machine cannot show the limit)."""
    with threadpool_limits(2, user_api="blas"):
        if max(blas_threads(), default=1) < 2:
            pytest.skip("BLAS runs one thread here whatever the limit")
        yield


def test_kernels_own_the_cores_limits_blas_while_running_and_restores(two_blas_threads):
    wrapped = kernels_own_the_cores(blas_threads)
    assert set(wrapped()) == {1}
    assert max(blas_threads()) == 2  # the caller's limit is back
    assert wrapped.__wrapped__ is blas_threads


def test_diagnose_fits_with_blas_on_one_thread_and_restores_after_an_error(two_blas_threads, monkeypatch):
    rec, _ = simulate_recording(Scenario(), 5.0, None, seed=1)
    seen = []

    def probe(*args, **kwargs):
        seen.append(blas_threads())
        raise Seen

    monkeypatch.setattr(report, "_fits", probe)
    with pytest.raises(Seen):
        report.diagnose(rec)
    assert seen and set(seen[0]) == {1}
    assert max(blas_threads()) == 2


def test_pool_workers_run_blas_on_one_thread(two_blas_threads):
    results = [threads for _, threads in map_unordered(blas_threads, [0, 1], workers=2)]
    assert len(results) == 2
    assert all(threads and set(threads) == {1} for threads in results)


# ---- fan_out: the helper processes that share one job's independent pieces -------------------

def _where(task):
    """(task, the process that ran it), after a pause long enough for both to take some."""
    time.sleep(0.05)
    return task, os.getpid()


def _fails_on_three(task):
    if task == 3:
        raise ValueError("task 3 fails")
    return task


def _dies_in_a_helper(task):
    """The task's double; a helper running it dies (as one killed by the system would)."""
    parent, x = task
    if os.getpid() != parent:
        os._exit(1)
    return 2 * x


@pytest.fixture
def helpers(monkeypatch):
    """Helpers switched on (the suite runs without them: its xdist workers fill the cores), a
    pool of this test's own, started; shut down afterwards."""
    if executors.default_workers() < 2:
        pytest.skip("one core here: fan_out runs every task in this process")
    monkeypatch.delenv(executors.HELPERS_VARIABLE, raising=False)
    for name, value in (("pool", None), ("started", []), ("count", 0), ("broken", False)):
        monkeypatch.setattr(executors._Helpers, name, value)
    assert executors.wait_for_helpers(__name__) > 0, "the helpers did not start"
    yield
    executors._Helpers.pool.shutdown(cancel_futures=True)


def test_fan_out_shares_the_tasks_with_a_helper_and_keeps_their_order(helpers):
    results = executors.fan_out(_where, range(12))
    assert [task for task, _ in results] == list(range(12))
    ran_in = {pid for _, pid in results}
    assert os.getpid() in ran_in and len(ran_in) > 1  # this process and a helper both took some


def test_fan_out_runs_here_only_when_the_variable_says_no_helpers(helpers, monkeypatch):
    monkeypatch.setenv(executors.HELPERS_VARIABLE, "0")
    assert {pid for _, pid in executors.fan_out(_where, range(6))} == {os.getpid()}


def test_fan_out_raises_a_tasks_error_and_gives_numba_its_threads_back(helpers):
    import numba

    threads = numba.get_num_threads()
    with pytest.raises(ValueError, match="task 3 fails"):
        executors.fan_out(_fails_on_three, range(8))
    assert numba.get_num_threads() == threads
    assert [task for task, _ in executors.fan_out(_where, range(4))] == list(range(4))
    assert numba.get_num_threads() == threads


def test_a_task_whose_helper_died_runs_here(helpers):
    assert executors.fan_out(_dies_in_a_helper, [(os.getpid(), x) for x in range(6)]) == [0, 2, 4, 6, 8, 10]
    assert executors._Helpers.broken  # and the broken pool is not used again
    assert executors.fan_out(_where, range(4)) == [(x, os.getpid()) for x in range(4)]


def _fan_out_here(tasks, answers=None):
    """fan_out(_where, tasks), put on `answers` (a queue) where given."""
    results = executors.fan_out(_where, tasks)
    if answers is not None:
        answers.put(results)
    return results


@pytest.mark.skipif(sys.platform != "linux", reason="fork is Linux's (unsafe on macOS, absent on Windows)")
def test_a_forked_child_runs_its_tasks_itself_and_ends(helpers):
    """A process the user forks after the helpers started: the parent's pool, its threads and
    pipes, is not the child's, and helpers of its own would keep it from ending (multiprocessing
    joins a child's children before anything tells them to stop): it runs its tasks itself."""
    import multiprocessing

    fork = multiprocessing.get_context("fork")
    answers = fork.Queue()
    child = fork.Process(target=_fan_out_here, args=(list(range(4)), answers))
    child.start()
    results = answers.get(timeout=120)
    child.join(timeout=60)
    assert child.exitcode == 0
    assert [task for task, _ in results] == list(range(4))
    assert {pid for _, pid in results} == {child.pid}


def test_a_daemonic_pool_worker_runs_its_tasks_itself(helpers):
    """Inside a multiprocessing.Pool worker (a daemon, which may not start processes) fan_out
    runs every task in that worker."""
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(1) as pool:
        results = pool.apply_async(_fan_out_here, (list(range(4)),)).get(timeout=120)
    assert [task for task, _ in results] == list(range(4))
    assert len({pid for _, pid in results}) == 1 and os.getpid() not in {pid for _, pid in results}


def test_a_script_without_a_main_guard_is_not_run_again_by_the_helpers(tmp_path):
    """A spawned process re-runs the parent's main script unless it is hidden: a user's script
    calling diagnose at its top level would run again in every helper."""
    if executors.default_workers() < 2:
        pytest.skip("one core here: no helpers")
    script = tmp_path / "user_script.py"
    script.write_text(
        "import os\n"
        "from inertia_gym import executors\n"
        "print('script ran', flush=True)\n"
        "assert executors.wait_for_helpers('os') > 0\n"
        "values = set(executors.fan_out(abs, range(-8, 0)))\n"
        "print('results', sorted(values), flush=True)\n")
    env = {k: v for k, v in os.environ.items() if k != executors.HELPERS_VARIABLE}
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env,
                          timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("script ran") == 1
    assert "results [1, 2, 3, 4, 5, 6, 7, 8]" in done.stdout


def test_diagnose_reports_the_same_with_helpers(helpers, monkeypatch):
    """Where a fit runs changes nothing: the report with helpers is the report without, to the
    last digit (a compound explanation: forward steps, refits and the backward check)."""
    rec, _ = simulate_recording(Scenario(tau_max=50.0), 10.0, ["gyro_bias", "actuator_misalignment"], seed=7)
    rec = dataclasses.replace(rec, meta={k: v for k, v in rec.meta.items() if k not in ("effect", "effects")})
    sent = executors._Helpers.sent
    with_helpers = json.dumps(report.diagnose(rec).report, sort_keys=True, default=str)
    assert executors._Helpers.sent > sent  # the helper took fits
    monkeypatch.setenv(executors.HELPERS_VARIABLE, "0")
    alone = json.dumps(report.diagnose(rec).report, sort_keys=True, default=str)
    assert with_helpers == alone
    assert len(json.loads(alone)["explanation"]) >= 2


class _BiasOfTheUser(GyroBias):
    """An effect a user registers in their own process (a helper does not know it)."""

    name = "users_gyro_bias"


def test_an_effect_registered_at_run_time_is_fitted_here(helpers, monkeypatch):
    """The helpers know the package's catalogue only: with an effect registered at run time
    (effects.register in a script) every fit runs in this process, and the new effect is fitted
    like the others."""
    monkeypatch.setitem(REGISTRY, _BiasOfTheUser.name, _BiasOfTheUser())
    rec, _ = simulate_recording(Scenario(tau_max=50.0), 5.0, ["gyro_bias"], seed=3)
    rec = dataclasses.replace(rec, meta={k: v for k, v in rec.meta.items() if k not in ("effect", "effects")})
    sent = executors._Helpers.sent
    result = report.diagnose(rec).report
    assert executors._Helpers.sent == sent
    fitted = {e["name"]: e["delta_bic"] for e in result["effects"]}
    assert fitted[_BiasOfTheUser.name] == pytest.approx(fitted["gyro_bias"], abs=1e-6)
