"""The one least-squares solver (estimation/solver.py): its step against the dense damped least
squares, its decrement, and its solves of known problems (a nonlinear curve, a limit's face,
a trust radius, several solves driven side by side)."""

import numpy as np
import pytest

from inertia_gym.estimation import solver
from inertia_gym.estimation.solver import Linearization, NormalBlocks, Problem, levenberg_marquardt, run


def _arrow_problem(seed: int, n_seg: int, rows: int, column_scales) -> tuple:
    """A random least-squares problem of the arrow shape NormalBlocks takes: (seg_of (N,),
    global columns g (N, P) scaled by column_scales, rate columns js (N, 3), residual r (N,))."""
    rng = np.random.default_rng(seed)
    seg_of = np.repeat(np.arange(n_seg), rows)
    g = rng.normal(size=(n_seg * rows, len(column_scales))) * np.asarray(column_scales)
    return seg_of, g, rng.normal(size=(n_seg * rows, 3)), rng.normal(size=n_seg * rows)


def _dense(g, js, seg_of, n_seg: int) -> np.ndarray:
    """The whole Jacobian: the global columns, then each segment's three rate columns."""
    p = g.shape[1]
    dense = np.zeros((g.shape[0], p + 3 * n_seg))
    dense[:, :p] = g
    for s in range(n_seg):
        dense[seg_of == s, p + 3 * s : p + 3 * s + 3] = js[seg_of == s]
    return dense


def test_normal_blocks_step_equals_the_dense_damped_least_squares():
    n_seg, p = 4, 5
    seg_of, g, js, r = _arrow_problem(0, n_seg, 30, np.ones(p))
    lam = 0.3
    blocks = NormalBlocks.of(Linearization(r, g, js, seg_of), n_seg, True)
    blocks.step(10.0)  # the blocks are formed once and serve every damping
    dg, ds = blocks.step(lam)
    dense = _dense(g, js, seg_of, n_seg)
    # Marquardt damping on every diagonal of the scaled normal equations
    a = dense.T @ dense
    a = a + lam * np.diag(np.diag(a))
    ref = np.linalg.solve(a, -dense.T @ r)
    np.testing.assert_allclose(dg, ref[:p], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(ds.ravel(), ref[p:], rtol=1e-8, atol=1e-10)
    # the segments' rates held: the damped least squares over the globals alone
    dg, ds = NormalBlocks.of(Linearization(r, g, js, seg_of), n_seg, False).step(lam)
    a = g.T @ g
    ref = np.linalg.solve(a + lam * np.diag(np.diag(a)), -g.T @ r)
    np.testing.assert_allclose(dg, ref, rtol=1e-8, atol=1e-10)
    assert not ds.any()


@pytest.mark.parametrize("seg_free", [True, False])
def test_the_decrement_is_the_fall_of_the_linear_least_squares(seg_free):
    """NormalBlocks.decrement: |r|^2 - min |r + J d|^2 over d, by the dense least squares."""
    n_seg = 3
    seg_of, g, js, r = _arrow_problem(2, n_seg, 25, [1e-3, 1.0, 1e3, 1.0])
    dense = _dense(g, js, seg_of, n_seg) if seg_free else g
    best = np.linalg.lstsq(dense, -r, rcond=None)[0]
    fall = r @ r - np.sum((r + dense @ best) ** 2)
    assert NormalBlocks.of(Linearization(r, g, js, seg_of), n_seg, seg_free).decrement() == pytest.approx(
        fall, rel=1e-9
    )


@pytest.mark.parametrize("seg_free", [True, False])
def test_a_parameter_the_residual_does_not_see_takes_no_step(seg_free):
    # a flexible mode's frequency while its coupling is zero, an inertia change's time while the
    # change is zero: the column is exactly zero, and the step along it must be too (not the
    # pseudo-inverse's round-off divided by 1e-300), the other entries the step without it
    n_seg = 3
    seg_of, g, js, r = _arrow_problem(1, n_seg, 20, [1e-3, 1.0, 1e3, 1.0])
    dead = g.copy()
    dead[:, 1] = 0.0
    for lam in (1e-9, 1e-3, 0.3):
        dg, ds = NormalBlocks.of(Linearization(r, dead, js, seg_of), n_seg, seg_free).step(lam)
        alive, ds_alive = NormalBlocks.of(
            Linearization(r, g[:, [0, 2, 3]], js, seg_of), n_seg, seg_free
        ).step(lam)
        assert dg[1] == 0.0
        np.testing.assert_allclose(dg[[0, 2, 3]], alive, rtol=1e-9, atol=0)
        np.testing.assert_allclose(ds, ds_alive, rtol=1e-9, atol=1e-12)
        if not seg_free:
            assert dg.shape == (4,)


def _exponential(x_true=(2.0, -1.5, 0.5), n=60, seed=0, noise=0.0):
    """Residuals and Jacobian of y = a exp(b t) + c fitted to noisy samples: (t, y)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2.0, n)
    a, b, c = x_true
    return t, a * np.exp(b * t) + c + noise * rng.normal(size=n)


def _curve(t, y):
    def residuals(x):
        return x[0] * np.exp(x[1] * t) + x[2] - y

    def linearize(x):
        e = np.exp(x[1] * t)
        return Linearization(residuals(x), np.stack([e, x[0] * t * e, np.ones_like(t)], 1))

    return residuals, linearize


def test_a_nonlinear_least_squares_problem_converges_to_its_minimum():
    t, y = _exponential()
    residuals, linearize = _curve(t, y)
    res = run(
        levenberg_marquardt(Problem(3, np.ones(3, bool)), np.array([1.0, -0.5, 0.0]), 100, tol=1e-20),
        linearize,
        residuals,
    )
    assert res.converged
    np.testing.assert_allclose(res.x, [2.0, -1.5, 0.5], rtol=1e-6)
    assert res.cost < 1e-12


def test_held_parameters_do_not_move_and_the_rest_fit_given_them():
    t, y = _exponential()
    residuals, linearize = _curve(t, y)
    free = np.array([True, True, False])
    res = run(
        levenberg_marquardt(Problem(3, free), np.array([1.0, -0.5, 0.7]), 200, tol=1e-20),
        linearize,
        residuals,
    )
    assert res.x[2] == 0.7
    # the optimum with c held: no step of (a, b) lowers the cost
    lin = linearize(res.x)
    grad = lin.g[:, :2].T @ lin.r
    assert np.abs(grad).max() < 1e-8 * max(1.0, float(lin.r @ lin.r))


def test_a_trust_radius_refuses_long_steps_and_the_solve_still_arrives():
    t, y = _exponential()
    residuals, linearize = _curve(t, y)
    seen = []

    def watched(x):
        seen.append(x.copy())
        return residuals(x)

    prob = Problem(3, np.ones(3, bool), max_step=np.array([0.05, 0.05, np.inf]))
    res = run(levenberg_marquardt(prob, np.array([1.0, -0.5, 0.0]), 500, tol=1e-20), linearize, watched)
    np.testing.assert_allclose(res.x, [2.0, -1.5, 0.5], rtol=1e-5)
    start = np.array([1.0, -0.5, 0.0])
    assert all(np.abs(x[:2] - start[:2]).max() <= 0.05 + 1e-12 for x in seen[:2])


def test_a_point_held_on_a_limit_moves_along_its_face():
    """Minimise |x - (2, 2)|^2 on the half-plane x0 + x1 <= 1, started on its edge: the projected
    step lands where it started, the step on the face reaches the nearest point (0.5, 0.5)."""
    target = np.array([2.0, 2.0])

    def project(x):
        excess = x[0] + x[1] - 1.0
        return x - max(excess, 0.0) / 2.0 * np.ones(2)

    def face(x):
        return np.array([[1.0, 1.0]]) if x[0] + x[1] >= 1.0 - 1e-12 else np.zeros((0, 2))

    prob = Problem(2, np.ones(2, bool), project=project, face=face)
    res = run(
        levenberg_marquardt(prob, np.array([1.0, 0.0]), 50, tol=1e-20),
        lambda x: Linearization(x - target, np.eye(2)),
        lambda x: x - target,
    )
    np.testing.assert_allclose(res.x, [0.5, 0.5], atol=1e-9)


def test_the_gram_and_the_qr_paths_give_the_same_step():
    """A well conditioned Jacobian's step comes from the normal matrix, an ill conditioned one's
    from its QR factor: both are the damped least-squares step."""
    rng = np.random.default_rng(3)
    for scales in ([1.0, 2.0, 3.0], [1.0, 1e-7, 1e7]):
        g = rng.normal(size=(40, 3)) @ np.diag(scales)
        g[:, 1] += 1e-9 * g[:, 0] if scales[1] < 1 else 0.0
        r = rng.normal(size=40)
        dg, _ = NormalBlocks.of(Linearization(r, g), 0, False).step(0.1)
        col = np.linalg.norm(g, axis=0)
        gs = g / col
        ref = (
            np.linalg.lstsq(np.vstack([gs, np.sqrt(0.1) * np.eye(3)]), np.r_[-r, np.zeros(3)], rcond=None)[0]
            / col
        )
        np.testing.assert_allclose(dg, ref, rtol=1e-6)


def test_solves_driven_side_by_side_reach_what_each_reaches_alone():
    t, y = _exponential(noise=0.01)
    residuals, linearize = _curve(t, y)
    starts = [np.array([1.0, -0.5, 0.0]), np.array([3.0, -2.0, 1.0])]
    alone = [
        run(levenberg_marquardt(Problem(3, np.ones(3, bool)), x0, 100), linearize, residuals) for x0 in starts
    ]
    gens = [levenberg_marquardt(Problem(3, np.ones(3, bool)), x0, 100) for x0 in starts]
    asked = {i: next(g) for i, g in enumerate(gens)}
    done = {}
    while asked:
        for i in list(asked):
            kind, arg = asked[i]
            answer = linearize(arg) if kind == "linearize" else np.array([residuals(x) for x in arg])
            try:
                asked[i] = gens[i].send(answer)
            except StopIteration as stop:
                done[i] = stop.value
                del asked[i]
    for i, res in enumerate(alone):
        np.testing.assert_array_equal(done[i].x, res.x)
    assert solver.SPECULATE >= 1


def _segmented(rng, rows, locals_, segments, globals_):
    """A Linearization of `segments` segments of `rows` rows each: js (N, L), g (N, P)."""
    js = rng.normal(size=(rows * segments, locals_))
    g = rng.normal(size=(rows * segments, globals_))
    seg_of = np.repeat(np.arange(segments), rows)
    return solver.Linearization(rng.normal(size=rows * segments), g, js, seg_of)


def test_the_globals_covariance_is_the_global_block_of_the_inverse_normal_matrix():
    """global_covariance by its definition: the globals' block of (J^T J)^-1 of the whole
    Jacobian, whose local columns belong to their own segment's rows."""
    rng = np.random.default_rng(2)
    lin = _segmented(rng, 40, 3, 4, 5)
    full = np.zeros((lin.g.shape[0], 5 + 3 * 4))
    full[:, :5] = lin.g
    for s in range(4):
        rows = lin.seg_of == s
        full[np.ix_(rows, 5 + 3 * s + np.arange(3))] = lin.js[rows]
    np.testing.assert_allclose(solver.global_covariance(lin, 4),
                               np.linalg.inv(full.T @ full)[:5, :5], rtol=1e-9, atol=1e-14)
    # a segment's rows may come in several runs (its gyro rows, then its attitude rows)
    mixed = rng.permutation(lin.seg_of.size)
    shuffled = solver.Linearization(lin.r[mixed], lin.g[mixed], lin.js[mixed], lin.seg_of[mixed])
    np.testing.assert_allclose(solver.global_covariance(shuffled, 4), solver.global_covariance(lin, 4),
                               rtol=1e-9, atol=1e-14)


def _nearly_hidden(globals_: int) -> tuple[solver.Linearization, float]:
    """Two segments whose rate columns are 1e4 in size, and a first global column that is the
    first rate column plus, in segment 0 only, 1e-6 n with n off every rate column there (the
    other globals zero): the Linearization and 1e-6 |n|, the column's only information."""
    rng = np.random.default_rng(3)
    lin = _segmented(rng, 50, 3, 2, 1)
    js = lin.js * 1e4
    rows = lin.seg_of == 0
    n = rng.normal(size=int(rows.sum()))
    basis = np.linalg.qr(js[rows])[0]
    n -= basis @ (basis.T @ n)  # off every local column of its segment
    g = np.zeros((lin.g.shape[0], globals_))
    g[rows, 0] = js[rows, 0] + 1e-6 * n
    g[~rows, 0] = js[~rows, 0]  # the other segment's local column: no information left there
    return solver.Linearization(lin.r, g, js, lin.seg_of), 1e-6 * float(np.linalg.norm(n))


def test_the_globals_covariance_keeps_what_a_segments_large_sensitivities_nearly_hide():
    """The nearly-hidden column (_nearly_hidden): its variance is 1 / (1e-6 |n|)^2. Formed from
    the normal equations, the Schur complement subtracts two numbers of 1e8 to find one of 1e-12
    and loses it to rounding; the projection keeps it to 1e-6."""
    lin, seen = _nearly_hidden(1)
    np.testing.assert_allclose(solver.global_covariance(lin, 2)[0, 0], 1.0 / seen ** 2, rtol=1e-6)


def test_the_globals_information_is_the_inverse_of_their_covariance_and_never_indefinite():
    """global_information by its definition: the inverse of the globals' block of (J^T J)^-1
    (the Schur complement of the locals). On the nearly-hidden column it stays positive at
    (1e-6 |n|)^2, where the normal equations' complement is rounding noise; a global the
    residual does not see gets a zero row and column."""
    rng = np.random.default_rng(2)
    lin = _segmented(rng, 40, 3, 4, 5)
    np.testing.assert_allclose(solver.global_information(lin, 4),
                               np.linalg.inv(solver.global_covariance(lin, 4)), rtol=1e-9, atol=1e-9)
    lin, seen = _nearly_hidden(2)
    info = solver.global_information(lin, 2)
    np.testing.assert_allclose(info[0, 0], seen ** 2, rtol=1e-6)
    assert np.all(info[1] == 0) and np.all(info[:, 1] == 0)


def test_with_every_global_held_the_step_is_the_segments_own_least_squares():
    """No free global: each segment's rates take their own damped least squares step."""
    n_seg = 3
    seg_of, _, js, r = _arrow_problem(4, n_seg, 20, [1.0])
    lam = 0.1
    dg, ds = NormalBlocks.of(Linearization(r, np.zeros((r.size, 0)), js, seg_of), n_seg, True).step(lam)
    assert dg.size == 0
    for s in range(n_seg):
        a = js[seg_of == s].T @ js[seg_of == s]
        ref = np.linalg.solve(a + lam * np.diag(np.diag(a)), -js[seg_of == s].T @ r[seg_of == s])
        np.testing.assert_allclose(ds[s], ref, rtol=1e-6)


def test_the_step_keeps_its_digits_where_the_segments_sensitivities_span_eight_orders():
    """Rate columns of 1, 1e4 and 1e8 (a long segment's sensitivities) and a global column nearly
    in their span: the step equals the dense damped least squares solved by QR to 1e-6, where
    eliminating the rates through the normal equations keeps only about four digits."""
    rng = np.random.default_rng(5)
    rows, n_seg, lam = 60, 2, 1e-12
    seg_of = np.repeat(np.arange(n_seg), rows)
    js = rng.normal(size=(rows * n_seg, 3)) * np.array([1.0, 1e4, 1e8])
    n = rng.normal(size=rows * n_seg)
    for s in range(n_seg):
        basis = np.linalg.qr(js[seg_of == s])[0]
        n[seg_of == s] -= basis @ (basis.T @ n[seg_of == s])
    g = np.column_stack([js @ np.ones(3) + 1e2 * n, rng.normal(size=rows * n_seg)])
    r = rng.normal(size=rows * n_seg) + 3 * n
    dg, ds = NormalBlocks.of(Linearization(r, g, js, seg_of), n_seg, True).step(lam)
    dense = _dense(g, js, seg_of, n_seg)
    diag = np.sum(dense ** 2, axis=0)
    floor = 1e-12 * diag[2:].max()
    damp = np.sqrt(lam * np.r_[diag[:2], np.maximum(diag[2:], floor)] + np.r_[0.0, 0.0, np.full(6, floor)])
    ref = np.linalg.lstsq(np.vstack([dense, np.diag(damp)]), -np.r_[r, np.zeros(8)], rcond=None)[0]
    np.testing.assert_allclose(dg, ref[:2], rtol=1e-6)
    np.testing.assert_allclose(ds.ravel(), ref[2:], rtol=1e-6, atol=1e-12)


def test_the_predicted_gain_is_the_linear_fall_over_the_free_globals_and_on_a_limit_its_faces():
    """solver.predicted_gain: over the free globals (and the segments' locals), the fall of the
    linear least squares, by the dense least squares; a held global takes no part; at a limit,
    the lesser of that and the fall kept on the limit's face."""
    n_seg = 3
    seg_of, g, js, r = _arrow_problem(4, n_seg, 25, [1.0, 1.0, 1.0])
    lin = Linearization(r, g, js, seg_of)
    free = np.array([True, False, True])
    dense = _dense(g[:, free], js, seg_of, n_seg)
    best = np.linalg.lstsq(dense, -r, rcond=None)[0]
    fall = r @ r - np.sum((r + dense @ best) ** 2)
    x = np.zeros(3 + 3 * n_seg)
    prob = Problem(3, free, segments=n_seg)
    assert solver.predicted_gain(prob, lin, x) == pytest.approx(fall, rel=1e-9)
    # on the face g0 = g2 (the limit's row (1, 0, -1)): the two free columns move as one
    on_face = Problem(3, free, segments=n_seg, face=lambda x: np.array([[1.0, 0.0, -1.0]]))
    joined = _dense((g[:, 0] + g[:, 2])[:, None], js, seg_of, n_seg)
    best = np.linalg.lstsq(joined, -r, rcond=None)[0]
    kept = r @ r - np.sum((r + joined @ best) ** 2)
    assert kept < fall
    assert solver.predicted_gain(on_face, lin, x) == pytest.approx(kept, rel=1e-9)
