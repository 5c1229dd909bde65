"""The fits: the solver on a model, the rigid fit and its polish, effects added to a fit.

solve and solve_many run the core Levenberg-Marquardt solver (estimation/solver.py) on a model,
the finite-difference Jacobians of several solves integrated in one batch; fit_nominal fits the
rigid model from its starts, polished runs fits on to their valley's floor, and fit_model adds
effects to a base fit from their starts and keeps its fits in d.cache. Independent fits are
shared with helper processes (fanned).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.objective import (
    Fit,
    Layout,
    _bounds,
    _free,
    _jacobian_columns,
    _jacobian_points,
    finish,
    jacobian,
    objective,
)
from inertia_gym.discrepancy.starts import (
    MODE_REACH,
    SHORT_SEGMENTS,
    Probe,
    _inertia_starts,
    _rows_and_base,
    initial_rates,
)
from inertia_gym.estimation import solver
from inertia_gym.executors import fan_out, helpers_ready

SIGNIFICANT_DELTA_BIC = 10.0  # "very strong" evidence on the Kass-Raftery scale
AMBIGUOUS_DELTA_BIC = 6.0
#: A rigid fit's continued start is polished on the record cut into these many times its own
#: segments in turn, before the record itself.
CONTINUATION_PIECES = (8, 4, 2)
#: Solver iterations: a screen, a start's trial run, a full fit; a fit stops when an iteration
#: gains less than CONVERGED in BIC units (cost gain / mean square per residual).
SCREEN_ITER, START_ITER, FULL_ITER, CONVERGED = 4, 4, 60, 1.0
#: The rigid fit (every ΔBIC's baseline) and the explanation's fit are polished on until the
#: undamped Gauss-Newton step predicts a gain under POLISH_DECREMENT in BIC units (at most
#: POLISH_ITER iterations; a step gaining under STEP_FLOOR is a stall), where their whitened
#: rms is within POLISH_MAX_RMS. On 1-s flights near the major or the middle axis the fits
#: crawl along a curved valley (the nutation fixes nearly one combination of the moments), where
#: single steps gain under CONVERGED long before the valley's floor. Stopped there (8 seeds,
#: the noise estimated from the data), the torque-free rigid fit sits 1-3 % off in the ratios,
#: its intervals miss the truth on 7 (major axis) and 3 (middle axis) of 8 seeds, and a gyro
#: scale or bias gains over 10 in BIC on 3 of the 8 clean flights near the major axis; with
#: drag, the explanation's fit sits 2-40 above its floor in cost, its intervals missing the
#: truth on 7 of 8 (major axis). A fit beyond POLISH_MAX_RMS leaves physics out: its intervals
#: are its misfit's (covariance() widens them by it), and a rigid one is only the effects'
#: start. Polished, the rigid fits of the real rotor throws with the rotor's momentum withheld
#: (hundreds of times the noise) lead 3 of 20 explanations into worse fits (1 into a better),
#: and the explanations of the real racquet tosses (1.5-8 times the noise) take up to 3.5 s
#: more a toss.
POLISH_MAX_RMS = 1.5
POLISH_ITER, POLISH_DECREMENT, STEP_FLOOR = 400, 0.1, 1e-4


# ------------------------------------------------------------------------------------------
# The solver
# ------------------------------------------------------------------------------------------


def _solver_problem(free, layout: Layout, d: Data, lb, ub) -> solver.Problem:
    """The core solver's view of a model: its globals and the segments' rates, its bounds and
    each effect's physical limits (Layout.feasible) by projection, their faces (Layout.face).
    """
    return solver.Problem(n_global=layout.n_global, free=np.asarray(free[:layout.n_global], bool),
                          segments=layout.segments, locals_free=bool(free[layout.n_global:].any()),
                          project=lambda x: layout.feasible(x, d), face=layout.face, bounds=(lb, ub))


def _linearization(r, g, js, d: Data) -> solver.Linearization:
    """The solver's Linearization of objective rows r with their columns (g for the free globals,
    js for the segments' rates): each gyro row marked with its segment, a penalty row with none.
    """
    seg_of = np.full(r.size, -1)
    seg_of[:3 * d.n_rows] = np.repeat(d.row_seg, 3)
    return solver.Linearization(r, g, js, seg_of)


def predicted_bic(fit: Fit, d: Data) -> float:
    """The BIC fit's model is predicted to reach from fit.x by one undamped Gauss-Newton step over
    every parameter it fits (solver.predicted_gain, its cost carried into the BIC's log of the
    mean square as finish counts the rows): the score test of what its last effect adds once the
    parameters it trades with move too. Exact for a model linear over the step, optimistic where
    it curves: a reason to fit the model jointly, never a fit.
    """
    layout = fit.layout
    free = _free(layout, d)
    lb, ub = _bounds(layout, d)
    lin = _linearization(*jacobian(fit.x, free, layout, d), d)
    cost = float(lin.r @ lin.r)
    if not np.isfinite(cost) or cost <= 0.0:
        return fit.bic
    gain = min(max(solver.predicted_gain(_solver_problem(free, layout, d, lb, ub), lin, fit.x), 0.0), cost)
    return fit.bic + d.effective_share * lin.r.size * np.log(max(cost - gain, 1e-300 * cost) / cost)


def solve(x0, free, layout: Layout, d: Data, lb, ub, max_iter: int,
          decrement: float | None = None) -> solver.Result:
    """The core solver (estimation/solver.py) over the free entries of x: its Result (x, cost,
    iterations, converged).

    Stops when a step gains less than CONVERGED in BIC units (the cost's gain over the mean
    square per residual: N log(mse) moves by that much), or after max_iter iterations. With
    `decrement` (BIC units), every step that gains more than STEP_FLOOR counts, and the solve
    stops where the undamped Gauss-Newton step predicts a gain under `decrement` (at a physical
    limit, the lesser of that and the same step's kept on the limit's face): a polish that
    follows a curved valley to its floor.
    """
    return solve_many([x0], free, layout, d, lb, ub, max_iter, decrement)[0]


def solve_many(x0s, free, layout: Layout, d: Data, lb, ub, max_iter: int,
               decrement: float | None = None) -> list[solver.Result]:
    """[solve(x0, ...) for x0 in x0s], the solves run side by side: the points each asks for
    next (its Jacobian's, or its steps') integrated in one batch with the others'. Each
    trajectory is integrated alone, so each solve's (x, cost) is the one it gives by itself;
    the batch only saves the calls' overhead (a 1-s toss's fits spend most of their time there).
    """
    spec = _solver_problem(free, layout, d, lb, ub)
    rel = CONVERGED if decrement is None else STEP_FLOOR
    gens = [solver.levenberg_marquardt(spec, np.asarray(x0, float), max_iter, rel_tol=rel,
                                       decrement=decrement) for x0 in x0s]
    known: dict = {}  # the rows already integrated at a point (an accepted step's)
    out: list = [None] * len(gens)
    asked = {i: next(g) for i, g in enumerate(gens)}
    while asked:
        order = list(asked)
        points, spans = [], []
        for i in order:
            kind, arg = asked[i]
            if kind == "residuals":
                batch = list(arg)
            else:
                batch = (([] if arg.tobytes() in known else [arg])
                         + list(_jacobian_points(arg, free, layout, d, False)))
            spans.append((len(points), len(batch)))
            points += batch
        rows = objective(np.array(points), layout, d) if points else np.zeros((0, 0))
        fresh = {}
        for i, (at, count) in zip(order, spans):
            kind, arg = asked[i]
            block = rows[at:at + count]
            if kind == "residuals":
                answer = block
                fresh.update({x.tobytes(): r for x, r in zip(arg, block)})
            else:
                r0 = known.get(arg.tobytes())
                if r0 is None:
                    r0, block = block[0], block[1:]
                answer = _linearization(*_jacobian_columns(arg, free, layout, d, r0, block, False), d)
            try:
                asked[i] = gens[i].send(answer)
            except StopIteration as done:
                out[i] = done.value
                del asked[i]
        known = fresh
    return out


# ------------------------------------------------------------------------------------------
# Fits
# ------------------------------------------------------------------------------------------


def fit_nominal(d: Data) -> Fit:
    """The rigid model alone: the user's model as given where the sidecar has a nominal inertia
    (only the segments' initial rates are fitted), else the inertia fitted (its trace pinned when
    the scale is not seen) with every segment's initial rates.

    Without a nominal several inertia starts are tried briefly and the best run to convergence.
    The fit returned is polished (polished()) where it is within POLISH_MAX_RMS of the noise.
    On a record of few segments the start chosen on short pieces and each start itself are run
    to convergence on the record; another start's fit replaces the chosen one where its BIC is
    lower by SIGNIFICANT_DELTA_BIC: the chosen start can lead the long trajectory into a far
    worse basin (a real racquet toss cut 0.05 s shorter at both ends: 1604x the noise, principal
    ratios (1, 0.06, 0.03), where the equation-error start reaches 175x and (1, 0.81, 0.20)),
    while basins within the margin are a tie the record does not decide (on real tosses with
    drag, rigid fits 0.3-1.8 apart in BIC with ratios (1, 0.97, 0.03) and (1, 0.94, 0.06)).
    On records of any length the linear start is also continued (_continued_start) and its fit
    replaces the chosen one where its BIC is lower by the same margin.
    """
    layout = Layout.of((), (), d)
    lb, ub = _bounds(layout, d)
    free = _free(layout, d)
    starts = [np.concatenate([phi, initial_rates(d)]) for phi in _inertia_starts(d)]
    if d.inertia0 is not None:
        return polished([finish(layout, solve(starts[0], free, layout, d, lb, ub, FULL_ITER).x, d)], d)[0]
    if d.segments < SHORT_SEGMENTS:  # the runs are independent: side by side (fanned)
        runs = fanned(_rigid_run, d, [{"layout": layout, "starts": starts}]
                      + [{"layout": layout, "x0": x0} for x0 in starts]
                      + [{"layout": layout, "x0": starts[0], "continued": True}])
        chosen, *direct = [finish(layout, run.x, d) for run in runs]
        chosen, best = polished([chosen, min(direct, key=lambda f: f.bic)], d)
        return best if best.bic < chosen.bic - SIGNIFICANT_DELTA_BIC else chosen
    runs = fanned(_rigid_run, d, [{"layout": layout, "x0": x0, "max_iter": START_ITER} for x0 in starts]
                  + [{"layout": layout, "x0": starts[0], "continued": True}])
    x = min(runs[:-1], key=lambda run: run.cost).x  # the first of least cost
    chosen, continued = polished([finish(layout, solve(x, free, layout, d, lb, ub, FULL_ITER).x, d),
                                  finish(layout, runs[-1].x, d)], d)
    return continued if continued.bic < chosen.bic - SIGNIFICANT_DELTA_BIC else chosen


def polished(fits: list[Fit], d: Data) -> list[Fit]:
    """The fits run on to their valley's floor (POLISH_ITER, POLISH_DECREMENT) where their
    whitened rms is within POLISH_MAX_RMS (side by side), the others as they are.
    """
    near = [i for i, f in enumerate(fits) if np.sqrt(np.mean(f.z ** 2)) <= POLISH_MAX_RMS]
    runs = fanned(_polish_run, d, [{"layout": fits[i].layout, "x0": fits[i].x} for i in near])
    out = list(fits)
    for i, run in zip(near, runs):
        out[i] = finish(fits[i].layout, run.x, d, fits[i].k)
    return out


def _polish_run(layout: Layout, d: Data, x0) -> solver.Result:
    """The model solved from x0 on to the valley's floor (POLISH_ITER, POLISH_DECREMENT)."""
    lb, ub = _bounds(layout, d)
    return solve(x0, _free(layout, d), layout, d, lb, ub, POLISH_ITER, POLISH_DECREMENT)


def _rigid_run(layout: Layout, d: Data, x0=None, starts=None, max_iter: int = FULL_ITER,
               continued: bool = False) -> solver.Result:
    """The rigid model solved for max_iter iterations from x0, or from the start
    that _best_start_on_short_segments chooses among `starts`; continued: from x0's globals
    carried over ever longer pieces of d first (_continued_start).
    """
    lb, ub = _bounds(layout, d)
    if x0 is None:
        x0 = _best_start_on_short_segments(starts, layout, d, lb, ub)
    elif continued:
        x0 = _continued_start(x0, layout, d)
    return solve(np.clip(x0, lb, ub), _free(layout, d), layout, d, lb, ub, max_iter)


def _continued_start(x0, layout: Layout, d: Data) -> np.ndarray:
    """x0's globals polished (POLISH_ITER, POLISH_DECREMENT) on d cut into CONTINUATION_PIECES
    times its segments in turn, then brought to d: each piece's initial rates those fitted on
    the last cut for a piece starting at the same sample, else its first sample. A short piece's
    basin is wide: on a thin body's 1.2-s flip (moments 1 : 0.985 : 0.02) the linear start's fit
    stops at 12x the noise in a basin of its own, where polished on 8 pieces, then 4, 2, 1 it
    reaches the noise; on a 6-s record of the same body the rates of its 1.2-s segments taken
    from their first samples (not the last cut's) leave one segment at 4000x.
    """
    glob, fitted = x0[:layout.n_global], {}

    def rates(cut: Data) -> np.ndarray:
        return np.concatenate([fitted.get(int(i), cut.w[i]) for i in cut.seg[:-1]])

    for count in CONTINUATION_PIECES:
        piece = d.resegmented(count * d.segments)
        if piece.segments <= d.segments:
            break
        lay = dataclasses.replace(layout, segments=piece.segments)
        lo, hi = _bounds(lay, piece)
        x = solve(np.clip(np.r_[glob, rates(piece)], lo, hi), _free(lay, piece), lay, piece, lo, hi,
                  POLISH_ITER, POLISH_DECREMENT).x
        glob = x[:lay.n_global]
        fitted = dict(zip(piece.seg[:-1].tolist(), x[lay.n_global:].reshape(-1, 3)))
    return np.r_[glob, rates(d)]


#: d.cache entries keyed by everything they depend on (fits and starts): what a helper may be
#: given and bring back (the others hold arrays tied to d's own objects, or a closure)
SHARED_CACHE = ("fit", "starts")


#: the catalogue as this module found it: a helper knows only these effects (an effect a user
#: registers at run time, e.g. in a script, exists in that process alone: fits run there)
BUILT_IN = dict(REGISTRY)
#: the module a helper imports before it takes fits: the whole engine (the fits it is sent
#: are functions of several of its modules)
ENGINE = "inertia_gym.discrepancy.fit"


def _helpers() -> int:
    """Helper processes ready to take the engine's fits (none where the catalogue is not
    BUILT_IN: a helper would not know the added effect).
    """
    return helpers_ready(ENGINE) if REGISTRY == BUILT_IN else 0


def _shared(key) -> bool:
    """A d.cache key of the SHARED_CACHE kinds."""
    return isinstance(key, tuple) and key[0] in SHARED_CACHE


def _in_turn(task) -> tuple:
    """fan_out's task: (fn(d=d, **kwargs), the shared cache entries it found), run on a copy of
    d's cache (the d sent to the helpers is never changed while they are sent it).
    """
    fn, shipped, kwargs = task
    d = dataclasses.replace(shipped, cache=dict(shipped.cache))
    out = fn(d=d, **kwargs)
    return out, {k: v for k, v in d.cache.items() if k not in shipped.cache and _shared(k)}


def fanned(fn, d: Data, calls: list[dict]) -> list:
    """[fn(d=d, **kwargs) for kwargs in calls], the calls shared with the helper processes
    (executors.fan_out; all here where the catalogue is not BUILT_IN); what they cached is
    added to d.cache. Each call runs on a copy of d with the shared part of its cache, here or
    in a helper: the results are the same either way.
    """
    shipped = dataclasses.replace(d, cache={k: v for k, v in d.cache.items() if _shared(k)})
    tasks = [(fn, shipped, kwargs) for kwargs in calls]
    results = []
    ran = fan_out(_in_turn, tasks) if _helpers() else [_in_turn(task) for task in tasks]
    for out, found in ran:
        for key, value in found.items():
            d.cache.setdefault(key, value)
        results.append(out)
    return results


def fit_model(names, forms, d: Data, base: Fit, joint: bool = True, start=None, extra_starts=(),
              omega_max: float | None = None) -> Fit:
    """Fit the effects `names` (in `forms`) jointly with the inertia and the segments' rates,
    the last one added to the fit `base` of the others (whose x starts everything else).

    joint=False fits only the new effect's parameters (everything else held) with SCREEN_ITER
    iterations per start: a cheap screen, refitted jointly after. start: one joint x to start
    from instead of the new effect's own starts (omega_max: the grid's fastest mode for it);
    extra_starts: joint xs tried beside them. Several starts each get START_ITER iterations and
    the best is run to convergence.

    The fit's x is kept in d.cache: the same fit asked again on the same rows (by a second
    search, or the selection repeated with the rows recounted) is only scored on d (finish, whose
    BIC counts d.effective_share), not solved again. Nothing of the solve depends on that share.
    """
    key = ("fit", tuple(names), tuple(forms), joint, omega_max, *_rows_and_base(d, base),
           None if start is None else np.asarray(start, float).tobytes(),
           tuple(np.asarray(x0, float).tobytes() for x0 in extra_starts))
    if key not in d.cache:
        fit = _fit_model(names, forms, d, base, joint, start, extra_starts, omega_max)
        d.cache[key] = (fit.layout, fit.x, fit.k)  # not its residuals: a long record has many fits
        return fit
    layout, x, k = d.cache[key]
    return finish(layout, x, d, k)


def _fit_model(names, forms, d: Data, base: Fit, joint: bool, start, extra_starts,
               omega_max: float | None) -> Fit:
    """fit_model's solve, without its cache."""
    layout = Layout.of(names, forms, d, base.layout.omega_max if omega_max is None else omega_max)
    new, form = layout.models[-1], layout.forms[-1]
    probe = Probe(layout, d, base)
    starts = ([start] if start is not None else probe.own_starts()) + list(extra_starts)
    if new.name == "flexible_mode" and starts:  # integrate finely enough for the fastest start
        i = layout.slices()[-1].start
        fastest = max(abs(x0[i]) for x0 in starts)
        layout = dataclasses.replace(layout, omega_max=min(MODE_REACH * fastest, new.bounds(form, d)[1][0]))
        probe = Probe(layout, d, base)
    lb, ub = _bounds(layout, d)
    free = _free(layout, d)
    if not joint:
        keep = np.zeros_like(free)
        keep[layout.slices()[-1]] = free[layout.slices()[-1]]
        free = keep
    k = int(_free(layout, d)[:layout.n_global].sum())
    if not starts:  # no valid start (e.g. no rigid body to attach a mode to): the base, effect zero
        return finish(layout, probe.x(np.zeros(layout.sizes[-1])), d, k)
    first = SCREEN_ITER if not joint else (START_ITER if len(starts) > 1 else FULL_ITER)
    if joint and len(starts) > 1 and d.segments < SHORT_SEGMENTS:  # solved on d below: first != FULL_ITER
        x = _best_start_on_short_segments(starts, layout, d, lb, ub)
    else:  # the first of least cost
        run = min(solve_many([np.clip(x0, lb, ub) for x0 in starts], free, layout, d, lb, ub, first),
                  key=lambda run: run.cost)
        x = run.x
    if joint and first != FULL_ITER:
        run = solve(x, free, layout, d, lb, ub, FULL_ITER)
    if joint:  # a start chosen elsewhere can lead astray: never worse than the effect at neutral
        neutral = probe.x(new.neutral(form, d, base))
        cost = probe.costs([run.x, neutral])
        if cost[1] < cost[0]:
            run = solve(neutral, free, layout, d, lb, ub, FULL_ITER)
    return finish(layout, run.x, d, k)


def _best_start_on_short_segments(starts, layout: Layout, d: Data, lb, ub) -> np.ndarray:
    """The start (joint x on d) that fits best after START_ITER iterations on d cut into
    SHORT_SEGMENTS segments, continued there to convergence and brought back to d.

    On a record of few segments a start whose inertia or effect is somewhat off can send the
    long trajectory astray, and its early cost then says little about where it leads; on short
    segments (each with its own initial rates) the same start stays near the data.
    """
    short = d.resegmented(SHORT_SEGMENTS)
    lay = dataclasses.replace(layout, segments=short.segments)
    lo, hi = _bounds(lay, short)
    free = _free(lay, short)
    rates = initial_rates(short)
    runs = solve_many([np.clip(np.r_[x0[:layout.n_global], rates], lo, hi) for x0 in starts], free, lay,
                      short, lo, hi, START_ITER)
    x = solve(min(runs, key=lambda run: run.cost).x, free, lay, short, lo, hi, FULL_ITER).x  # the first
    # of least cost
    first_rates = x[lay.n_global:lay.n_global + 3] if d.seg[0] == short.seg[0] else initial_rates(d)[:3]
    rates_back = np.r_[first_rates, initial_rates(d)[3:]]
    return np.r_[x[:layout.n_global], rates_back]
