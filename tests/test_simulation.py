"""Closed-loop simulation plumbing: the measurement schedule and the per-measurement log."""

import dataclasses

import numpy as np
import pytest

from inertia_gym.errors import ConfigError
from inertia_gym.estimation.inertia_param import dtheta_dphi, theta_from_phi
from inertia_gym.scenario import Scenario
from inertia_gym.simulation import _measurement_schedule, initial_state, run_segment


def _schedule_one_at_a_time(sc, rng, first, n_steps):
    """Definition: take a measurement at `first`, then draw one interval U[lo, hi] per
    measurement taken, while the measurement lies within the segment."""
    times, nxt = [], first
    while nxt <= n_steps:
        times.append(nxt)
        nxt += max(1, int(round(rng.uniform(*sc.meas_interval) / sc.dt)))
    return times, nxt - n_steps


@pytest.mark.parametrize("interval", [(0.1, 0.2), (0.01, 0.025), (0.3, 0.3), (5.0, 9.0)])
@pytest.mark.parametrize("first,n_steps", [(1, 1), (7, 5), (1, 3000), (25, 4321)])
def test_schedule_equals_drawing_intervals_one_at_a_time(interval, first, n_steps):
    sc = Scenario(meas_interval=interval)
    for seed in range(3):
        rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
        times, to_next = _measurement_schedule(sc, rng_a, first, n_steps)
        ref_times, ref_to_next = _schedule_one_at_a_time(sc, rng_b, first, n_steps)
        assert times.tolist() == ref_times
        assert to_next == ref_to_next
        # The generator is left where the one-at-a-time draws leave it.
        assert rng_a.standard_normal() == rng_b.standard_normal()


def test_logged_estimate_is_theta_and_delta_method_variance_at_the_last_update(paper):
    """The per-measurement log holds theta(phi) and diag(D P_phi D^T), D = dtheta/dphi: at the
    last measurement of a segment ending on it, they equal the final state's."""
    rngs = [np.random.default_rng(s) for s in range(2)]
    state = initial_state(paper, rngs)
    first = int(state.steps_to_meas.max())
    bursts = np.array([[[0, 100]], [[0, 100]]])
    end, trace = run_segment(paper, state, first + 30 * 20, bursts, (0.4, 4.0, 1.0),
                             np.eye(3)[1], rngs)
    for r in range(2):
        last = trace.n_meas[r] - 1
        stop = trace.meas_step[r, last]
        # Re-run run r exactly up to its last measurement: the final state is the logged one.
        rr = [np.random.default_rng(r)]
        again, _ = run_segment(paper, initial_state(paper, rr), int(stop), bursts[r:r + 1],
                               (0.4, 4.0, 1.0), np.eye(3)[1], rr)
        x, P = again.x[0], again.P[0]
        d = dtheta_dphi(x[7:13])
        assert np.allclose(trace.theta_hat[r, last], theta_from_phi(x[7:13]), rtol=1e-12)
        assert np.allclose(trace.theta_var[r, last], np.diag(d @ P[7:, 7:] @ d.T), rtol=1e-9)
        assert np.allclose(trace.theta_var[r, last], np.diag(again.P_theta()[0]), rtol=1e-9)



def test_with_rows_replaces_only_those_runs_and_copies():
    sc = Scenario()
    state = initial_state(sc, [np.random.default_rng(s) for s in range(4)])
    other = initial_state(sc, [np.random.default_rng(s) for s in (10, 11)])
    merged = state.with_rows([3, 1], other)
    for field in dataclasses.fields(state):
        new, old, rows = (getattr(s, field.name) for s in (merged, state, other))
        np.testing.assert_array_equal(new[[0, 2]], old[[0, 2]])
        np.testing.assert_array_equal(new[[3, 1]], rows)
        assert not np.shares_memory(new, old)
    assert not np.array_equal(merged.x, state.x)
    mask = np.array([False, True, False, True])
    np.testing.assert_array_equal(state.with_rows(mask, state.select(mask)).x, state.x)


def test_each_batch_size_runs_the_kernel_made_for_it_and_compiles_nothing_after_compile_loop():
    """A batch runs on the kernel suited to its size and the threads; after compile_loop() no
    batch compiles anything more."""
    from inertia_gym import simulation

    assert simulation._kernel_for(1, 2)[0] is simulation._segment_one
    assert simulation._kernel_for(3, 1)[0] is simulation._segment_lanes
    assert simulation._kernel_for(simulation.HALF_LANES, 2)[0] is simulation._segment_tasks_one_lane
    assert simulation._kernel_for(simulation.HALF_LANES + 1, 2) == (simulation._segment_tasks,
                                                                    (simulation.HALF_LANES,))
    assert simulation._kernel_for(simulation.LANES + 1, 1) == (simulation._segment_tasks,
                                                               (simulation.LANES,))
    simulation.compile_loop()
    kernels = [getattr(simulation, name) for name in simulation.KERNELS]
    compiled = [list(k.signatures) for k in kernels]
    assert all(len(signatures) == 1 for signatures in compiled)
    sc = Scenario()
    for batch in (1, 3, simulation.HALF_LANES + 2, simulation.LANES + 3):
        rngs = [np.random.default_rng(s) for s in range(batch)]
        run_segment(sc, initial_state(sc, rngs), 5, np.zeros((batch, 1, 2)), [0.1, 1.0, 1.0],
                    np.eye(3)[0], rngs)
    assert [list(k.signatures) for k in kernels] == compiled


def test_a_kernel_too_small_for_the_batch_or_unknown_is_refused():
    sc = Scenario()
    rngs = [np.random.default_rng(s) for s in range(2)]
    for kernel, words in (("_segment_one", "holds at most 1 runs"), ("nope", "must be one of")):
        with pytest.raises(ConfigError, match=words):
            run_segment(sc, initial_state(sc, rngs), 5, np.zeros((2, 0, 2)), [0.1, 1.0, 1.0],
                        np.eye(3)[0], rngs, kernel=kernel)


def test_compile_loop_compiles_the_kernels_named_and_refuses_an_unknown_one():
    """compile_loop(kernels) readies exactly those named (a warm-up splits the four between
    processes); a name outside KERNELS is refused."""
    from inertia_gym import simulation

    simulation.compile_loop(("_segment_lanes",))
    assert "_segment_lanes" in simulation._ready
    assert simulation._segment_lanes.signatures
    with pytest.raises(ConfigError, match="kernels must be among"):
        simulation.compile_loop(("_segment_lanes", "_segment_none"))


def test_a_failure_while_compiling_a_kernel_reaches_the_caller():
    """An error inside the first call's thread is raised in the caller's, and the kernel is not
    marked ready (the next call tries again)."""
    from inertia_gym import simulation

    def _broken_kernel(*args):
        raise ConfigError("no compiler here")

    with pytest.raises(ConfigError, match="no compiler here"):
        simulation._call_kernel(_broken_kernel, ())
    assert "_broken_kernel" not in simulation._ready


def test_the_loop_is_compiled_once_whatever_arrays_the_caller_passes():
    """A burst direction and xi shared by the runs (broadcast, read-only views), per-run
    arrays, non-contiguous slices, Fortran-ordered arrays and a read-only disturbance all reach
    the compiled loop as the same argument types: each other type would compile the loop
    once more."""
    from inertia_gym import simulation
    from inertia_gym.dynamics import NO_DISTURBANCE

    sc = Scenario()
    batch = 2
    rngs = [np.random.default_rng(s) for s in range(batch)]
    state = initial_state(sc, rngs)
    kernels = [getattr(simulation, name) for name in simulation.KERNELS]
    run_segment(sc, state, 20, np.zeros((batch, 1, 2)), np.tile([0.1, 1.0, 1.0], (batch, 1)),
                np.eye(3)[:batch], rngs)
    compiled = [list(k.signatures) for k in kernels]
    read_only = np.array(NO_DISTURBANCE)
    read_only.flags.writeable = False
    wide = np.zeros((batch, 3, 2), dtype=np.int32)
    run_segment(sc, state, 20, wide[:, ::3], np.array([0.1, 1.0, 1.0]), np.eye(3)[0], rngs,
                disturbance=read_only)
    run_segment(sc, state, 20, np.zeros((batch, 1, 2)), np.ones((batch, 6))[:, ::2],
                np.eye(4)[:batch, :3], rngs)
    run_segment(sc, state, 20, np.zeros((batch, 1, 2)), np.asfortranarray(np.ones((batch, 3))),
                np.asfortranarray(np.eye(3)[:batch]), rngs)
    assert [list(k.signatures) for k in kernels] == compiled


@pytest.mark.parametrize("estimator", ["ekf", "ukf"])
@pytest.mark.parametrize("tasks", ["LANES", "HALF_LANES", "one run", "one task"])
def test_a_batch_runs_each_run_exactly_as_alone(estimator, tasks):
    """The compiled loop advances runs in lock-step, LANES per task (when a batch of at most
    LANES runs is split over threads: HALF_LANES per task, or one run per task on one lane when
    it has at most HALF_LANES runs; on one thread, one task of LANES lanes): every run of a
    batch (more runs than one task holds, unequal lengths, one of zero steps, one diverged)
    gives bit for bit what it gives alone."""
    import numba

    threads = numba.get_num_threads()
    if tasks in ("HALF_LANES", "one run"):  # split only over two or more threads
        if numba.config.NUMBA_NUM_THREADS < 2:
            pytest.skip("a batch of at most LANES runs is split only over two or more threads")
        numba.set_num_threads(2)
    try:
        _batch_against_alone(estimator, tasks)
    finally:
        numba.set_num_threads(threads)


def _batch_against_alone(estimator, tasks):
    from inertia_gym.simulation import HALF_LANES, LANES

    sc = Scenario(estimator=estimator)
    batch = {"LANES": LANES + 3, "HALF_LANES": HALF_LANES + 3, "one run": HALF_LANES,
             "one task": LANES - 1}[tasks]
    rngs = [np.random.default_rng(s) for s in range(batch)]
    state = initial_state(sc, rngs)
    diverged = batch - 1
    state = state.with_rows([diverged], dataclasses.replace(state.select(diverged),
                                                            diverged=np.array([True])))
    n_steps = [300 + 37 * r for r in range(batch)]
    n_steps[2] = 0
    bursts = np.array([[[5 * r, 5 * r + 40], [200, 230]] for r in range(batch)])
    xi = np.c_[np.linspace(0.0, 0.4, batch), np.linspace(1.0, 4.0, batch), np.ones(batch)]
    v = np.eye(3)[np.arange(batch) % 3]
    end, trace = run_segment(sc, state, n_steps, bursts, xi, v,
                             [np.random.default_rng(100 + s) for s in range(batch)],
                             kernel="_segment_lanes" if tasks == "one task" else None)
    for r in range(batch):
        if n_steps[r] == 0:
            continue
        alone, alone_trace = run_segment(sc, state.select(r), n_steps[r], bursts[r:r + 1],
                                         xi[r:r + 1], v[r:r + 1], [np.random.default_rng(100 + r)])
        for field in dataclasses.fields(end):
            assert np.array_equal(getattr(end, field.name)[r], getattr(alone, field.name)[0],
                                  equal_nan=True), field.name
        for field in dataclasses.fields(trace):
            mine, theirs = getattr(trace, field.name)[r], getattr(alone_trace, field.name)[0]
            if mine.ndim:
                mine = mine[: theirs.shape[0]]
            assert np.array_equal(mine, theirs, equal_nan=True), field.name
