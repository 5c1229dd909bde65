import numpy as np

from inertia_gym.estimation.inertia_param import INTERIOR_SHARE, interior, nearest_realizable


def test_an_interior_start_keeps_the_trace_and_each_moment_below_the_others_sum_by_its_share():
    """interior by its definition: (1 - s) J + s trace/3 I, on a flat plate's inertia (on the
    limit nearest_realizable projects onto) strictly inside, each moment at least s trace/3 below
    the sum of the other two, its axes and trace kept."""
    axes = np.linalg.qr(np.random.default_rng(5).normal(size=(3, 3)))[0]
    plate = nearest_realizable((axes * [1.0, 0.45, 0.05]) @ axes.T)
    start = interior(plate)
    trace = np.trace(plate)
    np.testing.assert_allclose(start, (1 - INTERIOR_SHARE) * plate + INTERIOR_SHARE * trace / 3 * np.eye(3))
    np.testing.assert_allclose(np.trace(start), trace)
    moments = np.linalg.eigvalsh(start)
    margin = moments.sum() - 2 * moments  # each moment's distance below the sum of the other two
    assert np.all(margin >= INTERIOR_SHARE * trace / 3 * (1 - 1e-9))
    np.testing.assert_allclose(axes.T @ start @ axes, np.diag(np.diag(axes.T @ start @ axes)), atol=1e-12)
