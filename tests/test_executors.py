"""The thread budget of the compiled work: BLAS held to one thread while diagnose's kernels run
and in every pool worker; the caller's own limits restored afterwards, also after an error."""

from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from inertia_gym.discrepancy import report
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


def test_pool_workers_run_blas_on_one_thread():
    if max(blas_threads(), default=1) < 2:
        pytest.skip("BLAS runs one thread here by default: a worker would too, limited or not")
    results = [threads for _, threads in map_unordered(blas_threads, [0, 1], workers=2)]
    assert len(results) == 2
    assert all(threads and set(threads) == {1} for threads in results)
