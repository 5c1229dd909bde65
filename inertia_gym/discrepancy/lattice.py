"""A gyro read on a lattice coarser than its motion and noise move it.

Its rounding error is a function of the rate, not white noise. rounding_runs says which axes are
read so, lattice_level reads their noise level by simulating the rounding, and records of a
fit's prediction read through the lattice (_rounding_records) give the spread the rounding adds
to a fit's estimates (lattice_spread) and, in rounding.py, what an effect gains from it alone.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.fitting import FULL_ITER, solve
from inertia_gym.discrepancy.objective import Fit, Layout, _bounds, _free, finish, predict
from inertia_gym.sensors import lattice_replays, read_on_lattice

#: An axis read on a lattice (sensors.quantisation_step) whose kept samples repeat in runs of this
#: many or more on average is read coarser than its motion and noise move it: its rounding error
#: is a function of the rate, not white noise, and the same at every pass of the rate through a
#: value (a torque-free tumble repeats its rates each period). Fits gain by tracing it: on a slow
#: tumble read in steps of 20 times its noise, with no effect in the data, single effects
#: improve the BIC by up to 330, enough for one to three effects to explain every record.
ROUNDING_RUNS = 2.0
#: The rounded nominal models rounding_floors reads: the data's own lattice and lattices shifted
#: by random fractions of a step (what a fit gains from the rounding scatters with the lattice's
#: place: from below 0 to 740 over four shifts of one record)
ROUNDING_DRAWS = 4
#: Refits on the lattice behind a coarse gyro's share of the covariance (lattice_spread)
LATTICE_REPLAYS = 8


def rounding_runs(d: Data) -> np.ndarray:
    """(3,) the mean length of the runs of equal consecutive kept samples on each axis read on a
    lattice (d.notes["quantisation_step"] > 0); 0 on an axis that is not.
    """
    kept = d.w[d.row >= 0]
    out = np.zeros(3)
    for i in np.flatnonzero(d.notes["quantisation_step"] > 0):
        out[i] = kept.shape[0] / (np.count_nonzero(np.diff(kept[:, i])) + 1)
    return out


#: Noise levels under the rounding tried by lattice_level, in steps of the lattice
LEVEL_TRIALS = np.linspace(0.0, 1.0, 41)


def _third_spread(w) -> np.ndarray:
    """(3,) the mean absolute deviation of the third differences of w (n, 3) from their median:
    the spread lattice_level matches (continuous in the noise, where the median absolute
    deviation of differences in whole steps reads one step or none).
    """
    d3 = np.diff(w, n=3, axis=0)
    return np.mean(np.abs(d3 - np.median(d3, axis=0)), axis=0)


def lattice_level(d: Data, nominal: Fit) -> Data:
    """The data d with the noise level of each axis read coarser than its motion and noise move it
    (rounding_runs >= ROUNDING_RUNS) read again by simulating the rounding, where the level was
    read from the data: the nominal fit's rates plus white noise of LEVEL_TRIALS steps, rounded
    to the axis's lattice; the noise whose rounded rates' third differences spread as the data's
    do (_third_spread) gives the level, the rms of those rounded rates about the fit's. The
    differences of rounded samples miss the part of the rounding error that follows the rate:
    a slow tumble in steps of 0.01 rad/s with noise of a quarter step reads 0.0029-0.0033 rad/s
    where its samples are 0.0038 off the truth, and its clean fits would be flagged unexplained
    at 1.3 times that level. d itself where the level is the sidecar's or no axis is so read.
    """
    coarse = rounding_runs(d) >= ROUNDING_RUNS
    if d.sigma_source == "sidecar" or not coarse.any() or not np.isfinite(nominal.bic):
        return d
    kept = d.row >= 0
    rate = predict(nominal.x[None], nominal.layout, d)[0][kept]
    step = d.notes["quantisation_step"]
    noise = np.random.default_rng(0).normal(size=rate.shape)
    spreads, levels = [], []
    for share in LEVEL_TRIALS:
        rounded = read_on_lattice(rate + share * step * noise, step)
        spreads.append(_third_spread(rounded))
        levels.append(np.sqrt(np.mean((rounded - rate) ** 2, axis=0)))
    spreads = np.maximum.accumulate(np.array(spreads), axis=0)  # (trials, 3), made non-decreasing
    levels, real = np.array(levels), _third_spread(d.w[kept])
    sigma = d.sigma.copy()
    for i in np.flatnonzero(coarse):
        sigma[i] = np.interp(real[i], spreads[:, i], levels[:, i])
    return dataclasses.replace(d, sigma=sigma, sigma_source=d.sigma_source + (
        "; on the axes read coarser than their motion and noise move them, by simulating the "
        "rounding of the rigid fit's rates"))


def _rounding_records(d: Data, fit: Fit, draws: int = ROUNDING_DRAWS):
    """The `draws` records rounding_floors reads, holding fit's prediction and nothing but
    the rounding: d with its gyro samples replaced by that prediction plus the noise beneath the
    step (sqrt(sigma^2 - step^2 / 12)), rounded to d's lattice, then to lattices shifted by a
    random fraction of a step (seeded), its rows counted as independent.
    """
    step = d.notes["quantisation_step"]
    beneath = np.sqrt(np.maximum(d.sigma ** 2 - step ** 2 / 12.0, 0.0))
    rate = predict(fit.x[None], fit.layout, d)[0]
    for w in lattice_replays(rate, beneath, step, draws, first_unshifted=True):
        yield dataclasses.replace(d, w=w, cache={}, rounding_floor={}, effective_share=1.0)


def lattice_spread(fit: Fit, d: Data, idx) -> np.ndarray:
    """(k, k) the mean outer product of the errors of fit.x's entries idx (k,) over refits of
    fit's model, from fit.x, on LATTICE_REPLAYS records of its prediction read on d's lattice
    (_rounding_records: the noise beneath the step added, the lattice shifted by a random
    fraction of a step), where an axis runs ROUNDING_RUNS samples or more on one value; zeros
    elsewhere. The rounding error follows the motion, and neither the residual's level nor its
    correlation counts it: on 600-s tumbles read in steps of 20x the noise the principal ratios'
    95 % intervals hold the truth on 1 of 12 without it. The spread holds the noise's share too,
    which the information already counts: a little too wide where the noise outweighs the
    rounding. Refits that blow up are left out (lattice_refits_counted: how many are not).
    Kept in d.cache per fit.
    """
    return _lattice_refits(fit, d, idx)[0]


def lattice_refits_counted(fit: Fit, d: Data) -> int:
    """How many of the LATTICE_REPLAYS refits lattice_spread counts in fit's covariance on d: 0
    where the gyro reads finely enough, fit has no finite BIC, or every refit blew up.
    """
    return _lattice_refits(fit, d, np.flatnonzero(_free(fit.layout, d)[:fit.layout.n_global]))[1]


def _lattice_refits(fit: Fit, d: Data, idx) -> tuple[np.ndarray, int]:
    """lattice_spread's matrix and the number of refits it counts."""
    if not np.any(rounding_runs(d) >= ROUNDING_RUNS) or not np.isfinite(fit.bic):
        return np.zeros((idx.size, idx.size)), 0
    key = ("lattice_spread", fit.names, fit.forms, fit.x.tobytes(), d.sigma.tobytes(), d.row.tobytes())
    if key not in d.cache:
        gaps = [_refit(fit.layout, fit.x, rec).x[idx] - fit.x[idx]
                for rec in _rounding_records(d, fit, LATTICE_REPLAYS)]
        gaps = [g for g in gaps if np.all(np.isfinite(g))]  # (a refit that blew up says nothing)
        spread = sum((np.outer(g, g) for g in gaps), np.zeros((idx.size, idx.size))) / max(len(gaps), 1)
        d.cache[key] = (spread, len(gaps))
    return d.cache[key]


def _refit(layout: Layout, x0, d: Data) -> Fit:
    """The model `layout` solved on d from x0 to convergence."""
    lb, ub = _bounds(layout, d)
    return finish(layout, solve(np.clip(x0, lb, ub), _free(layout, d), layout, d, lb, ub, FULL_ITER).x, d)
