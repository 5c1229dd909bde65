"""The statistics of a fit: its information, covariance and intervals, and the share of its
residual rows that are independent.

information is the Gauss-Newton information of the global entries with the segments' rates
eliminated, covariance its inverse (estimation.solver: global_information, global_covariance),
widened by the misfit and, on a coarsely read gyro, by the lattice's spread (lattice.py);
intervals carries it to every effect's named parameters by the delta method; effective_share is
the share the BICs and the covariance count the rows with.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy import stats

from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.effects import EffectModel
from inertia_gym.discrepancy.lattice import lattice_spread
from inertia_gym.discrepancy.objective import Fit, _free, _steps, jacobian, named_params
from inertia_gym.estimation import solver
from inertia_gym.estimation.longrun import correlation_lags


def _linearization(fit: Fit, d: Data) -> tuple[solver.Linearization, np.ndarray]:
    """The fit's residual linearized in its free global entries and its segments' rates (central
    differences), and the free global entries' indices.
    """
    layout = fit.layout
    free = _free(layout, d)
    r, g, js = jacobian(fit.x, free, layout, d, central=True)
    seg_of = np.full(r.size, -1)
    seg_of[:d.n_rows * 3] = np.repeat(d.row_seg, 3)
    return solver.Linearization(r, g, js, seg_of), np.flatnonzero(free[:layout.n_global])


def _widening(fit: Fit, d: Data) -> float:
    """The factor the model error widens the covariance by: the whitened residual's mean square
    where it exceeds 1, over the share of its rows that are independent (effective_share). Rows
    correlated over tau of them carry the information of 1/tau as many: the same count the BICs
    are recounted with. Without it, on a 1-s racquet toss with AR(1) gyro noise (coefficient 0.9
    per row, stated level given) the shape's 95 % intervals cover the truth on 8 of 20 seeds;
    with it on 13 (tests/discrepancy/test_fit.py), and white noise (a share of 1) gives the
    same intervals as without it.
    """
    mse = float(np.mean(fit.z ** 2)) if np.all(np.isfinite(fit.z)) else 1.0
    return max(1.0, mse) / effective_share(d, fit)


def information(fit: Fit, d: Data) -> tuple[np.ndarray, np.ndarray, float]:
    """The information of the free global entries of fit.x with the segments' rates eliminated
    (solver.global_information), their indices, and the factor the model error widens the
    covariance by (_widening).
    """
    lin, idx = _linearization(fit, d)
    return solver.global_information(lin, d.segments), idx, _widening(fit, d)


def covariance(fit: Fit, d: Data) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the free global entries of fit.x and their indices: the globals' block of
    the inverse information with the segments' rates eliminated (solver.global_covariance),
    widened by the model-error factor (_widening), plus, on a gyro read coarser than its motion
    and noise move it, the spread of fit's refits on its prediction read on the lattice
    (lattice_spread).
    """
    lin, idx = _linearization(fit, d)
    cov = solver.global_covariance(lin, d.segments) * _widening(fit, d)
    return cov + lattice_spread(fit, d, idx), idx


def _flat_params(model: EffectModel, p, d: Data) -> np.ndarray:
    """named_params of model at p, flattened in order into one vector."""
    return np.concatenate([np.ravel(v) for v in named_params(model, p, d).values()])


def intervals(fit: Fit, d: Data, level: float = 0.95) -> dict:
    """Two-sided intervals of every named parameter of fit's effects: {name: {param: {lo, hi}}}.

    From covariance() by the delta method through each class's named parameters as reported
    (named_params: an inertia_offset's inertia at the nominal's trace where the scale is not
    seen; through the bare unpack its intervals would be at the held gauge's trace, the 95 %
    interval of Ixx of zero width and off the estimate on 7 of 7 wrong nominals); held
    parameters (a scanned t_change, bookkeeping) get no width from the fit.
    """
    cov_free, idx = covariance(fit, d)
    layout = fit.layout
    cov = np.zeros((layout.n_global, layout.n_global))
    cov[np.ix_(idx, idx)] = cov_free
    k = float(stats.norm.ppf(0.5 + level / 2))
    steps = _steps(fit.x, layout, d)
    out = {}
    for model, sl in zip(layout.models, layout.slices()):
        p = fit.x[sl]
        sub = cov[sl, sl]
        named = named_params(model, p, d)
        flat_at = functools.partial(_flat_params, model, d=d)
        flat = flat_at(p)
        jac = np.zeros((flat.size, p.size))
        for j in range(p.size):
            h = steps[sl][j]
            up, dn = p.copy(), p.copy()
            up[j] += h
            dn[j] -= h
            jac[:, j] = (flat_at(up) - flat_at(dn)) / (2 * h)
        half = k * np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, sub, jac), 0.0))
        res, i = {}, 0
        for key, v in named.items():
            size, shape = np.size(v), np.shape(v)
            res[key] = {"lo": (flat[i:i + size] - half[i:i + size]).reshape(shape),
                        "hi": (flat[i:i + size] + half[i:i + size]).reshape(shape)}
            i += size
        out[model.name] = res
    return out


def _segment_residuals(d: Data, fit: Fit) -> list[np.ndarray]:
    """The whitened residual rows of fit, segment by segment, each less its mean (segments of at least
    8 rows); [] where the residual is not finite or the record too short to tell.
    """
    z = fit.z
    if not np.all(np.isfinite(z)) or d.n_rows < 16:
        return []
    pieces = [z[d.row_seg == s] for s in range(d.segments)]
    return [p - p.mean(axis=0) for p in pieces if p.shape[0] >= 8]


def residual_correlated(d: Data, fit: Fit) -> bool:
    """Whether fit's whitened residual rows stay correlated within segments at some lag (the
    autocorrelation test of estimation.longrun.correlation_lags): structure is left, a smooth
    misfit or an oscillation alike. An oscillation's autocorrelation alternates in sign and sums
    to about nothing, so effective_share reads it as white; this test does not.
    """
    pieces = _segment_residuals(d, fit)
    return bool(pieces) and correlation_lags(np.vstack(pieces)) > 0


def effective_share(d: Data, fit: Fit) -> float:
    """1/tau: the share of fit's residual rows that are independent, tau = 1 + 2 sum_l
    (1 - l/(L+1)) rho_l the integrated autocorrelation (Bartlett weights) of the whitened rows
    over the L lags they stay correlated (estimation.longrun.correlation_lags), within segments.

    White residuals give 1. A smooth misfit the catalogue does not explain (real recordings) is
    correlated over many rows: counted as independent it would make every extra parameter that
    absorbs a little of it look significant, a flexible one most of all.
    """
    pieces = _segment_residuals(d, fit)
    if not pieces:
        return 1.0
    lags = max(correlation_lags(np.vstack(pieces)), 0)
    if lags == 0:
        return 1.0
    acf = np.zeros(lags + 1)
    weight = 0.0
    for p in pieces:
        m = p.shape[0]
        spec = np.fft.rfft(p, n=2 * m, axis=0)
        a = np.fft.irfft(spec * np.conj(spec), axis=0)[:lags + 1]
        a = (a / np.clip(a[0], 1e-300, None)).mean(axis=1)
        a = np.pad(a, (0, lags + 1 - a.size))
        acf += m * a
        weight += m
    acf /= weight
    tau = 1.0 + 2.0 * np.sum((1.0 - np.arange(1, lags + 1) / (lags + 1.0)) * acf[1:])
    return float(1.0 / max(tau, 1.0))
