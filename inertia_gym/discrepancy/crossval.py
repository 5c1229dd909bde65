"""Whether the effects an explanation adds after its leader predict the record where they were not
fitted (time-blocked cross-validation).

A BIC gain says that a term lowers the residual in the rows it was fitted to. On a real record the
leader leaves a smooth misfit that no catalogue effect models, and a flexible term (a free
momentum profile, a bias, a dissipation) can follow part of it there and gain in BIC without being
physics the body has: it makes the residual whiter, but it does not carry over to time it has not
seen. Each segment's rows are cut into FOLDS + 1 contiguous blocks; the first (where the
segment's initial state is fitted) always stays, and block k after it of every segment is held
out in turn. The explanation is refitted on the rest (from its own fit: the inertia, the initial
states and the tested effect move; a tested time profile's knots inside the block first drawn
through its knots outside, since their fitted values saw the rows held out) and scored on the
rows held out. An added effect stays only where the explanation with it predicts the held-out
rows better than the explanation without it (the smaller held-out residual sum: the held-out
Gaussian likelihood with the variance profiled out). The leader is not judged here: it clears
its margin against the rigid model alone.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.fitting import FULL_ITER, fanned, solve
from inertia_gym.discrepancy.objective import Fit, _bounds, _free, whitened

#: Blocks per segment held out in turn (after its first): each a fifth of a segment, long beside
#: the few rows a smooth misfit stays correlated over, so a held-out block is predicted by the
#: model through it, not by its neighbours' residual.
FOLDS = 4
#: Weight-free rows: a held-out row's noise scale, so large that it pulls on no fit.
HELD_OUT_SCALE = 1e8


def folds(d: Data) -> np.ndarray:
    """(n_rows,) the fold of each row, -1 .. FOLDS-1: each segment cut into FOLDS + 1 equal
    contiguous blocks, its first never held out (fold -1: the segment's initial state is fitted
    there, so a held-out block is predicted forward from it, never extrapolated back to it) and
    the k-th after it in fold k.
    """
    fold = np.zeros(d.n_rows, np.int64)
    for s in range(d.segments):
        rows = np.flatnonzero(d.row_seg == s)
        fold[rows] = np.minimum(np.arange(rows.size) * (FOLDS + 1) // max(rows.size, 1), FOLDS) - 1
    return fold


def _held_out_sum(fit: Fit, d: Data, fold: np.ndarray, k: int, tested: str | None) -> float:
    """The whitened residual sum over the rows of fold k of fit's model refitted on the others:
    the inertia, the segments' initial states and the tested effect's parameters move; every
    other effect stays as fitted to the whole record (a profile's knots in the rows held out have
    nothing left to fit them, and would otherwise be extrapolated freely).
    """
    held = fold == k
    train = dataclasses.replace(d, row_scale=np.where(held, HELD_OUT_SCALE, d.row_scale), cache={})
    lb, ub = _bounds(fit.layout, train)
    free = _free(fit.layout, train)
    for name, part in zip(fit.layout.names, fit.layout.slices()):
        if name != tested:
            free[part] = False
    x0 = _profile_from_rows_kept(fit, d, held, tested)
    x = solve(np.clip(x0, lb, ub), free, fit.layout, train, lb, ub, FULL_ITER).x
    z = whitened(np.asarray(x, float)[None], fit.layout, d)[0]
    return float(np.sum(z[held] ** 2)) if np.all(np.isfinite(z[held])) else np.inf


def _profile_from_rows_kept(fit: Fit, d: Data, held: np.ndarray, tested: str | None) -> np.ndarray:
    """fit.x with the tested effect's time profile (a varying form's knot values) at the knots
    inside the rows held out (held (n_rows,) bool) drawn through the knots outside them
    (linearly between them, held at the nearest one beyond them): those values were fitted to
    the held-out rows, which the refit does not see, so kept they would carry the held-out rows
    into their own prediction. fit.x itself where the effect has no profile or fewer than two
    knots outside.
    """
    x = np.array(fit.x, float)
    if tested is None:
        return x
    part = fit.layout.slices()[fit.layout.names.index(tested)]
    model = fit.layout.models[fit.layout.names.index(tested)]
    params = model.unpack(x[part])
    if "profile" not in params:
        return x
    knot_t = np.asarray(params["profile_t"], float)
    profile = np.array(params["profile"], float).reshape(knot_t.size, -1)
    sample_held = np.zeros(d.t.size, bool)
    kept_row = d.row >= 0
    sample_held[kept_row] = held[d.row[kept_row]]
    inside = sample_held[np.clip(np.searchsorted(d.t, knot_t), 0, d.t.size - 1)]
    if not inside.any() or (~inside).sum() < 2:
        return x
    for col in range(profile.shape[1]):
        profile[inside, col] = np.interp(knot_t[inside], knot_t[~inside], profile[~inside, col])
    x[part.stop - profile.size:part.stop] = profile.ravel()  # the profile closes each varying vector
    return x


def held_out_sums(fits: list[Fit], d: Data, tested: list) -> list[float]:
    """Each fit's residual sum over the rows held out in turn, its model refitted on the rest
    with its effect tested[i] (None: none) moving (every fold of every fit run side by side).
    """
    fold = folds(d)
    jobs = [{"fit": f, "fold": fold, "k": k, "tested": t} for f, t in zip(fits, tested)
            for k in range(FOLDS)]
    sums = fanned(_held_out_sum, d, jobs)
    return [float(sum(sums[i * FOLDS:(i + 1) * FOLDS])) for i in range(len(fits))]


def predicts_words(ratio: float) -> str:
    """Why an added effect is left out: the held-out residual sum with it over that without it."""
    return (f"it does not predict the record where it was not fitted: with it, the stretches held "
            f"out in turn (time-blocked cross-validation, {FOLDS} folds) are fitted "
            f"{ratio:.2f}x as badly as without it (held-out residual sum)")
