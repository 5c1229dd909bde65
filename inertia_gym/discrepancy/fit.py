"""Fit the rigid model and the catalogue's effects to a recording by output error; rank by BIC.

The model is the truth simulator itself: the effects' own physics hooks (effects/, assembled
by model.py) integrated by model_dynamics.propagate_model_batch predict the gyro reading at every
sample from the body's initial rates, and a fit minimises the whitened difference from the
recorded reading (output error: no derivative of the noisy gyro enters, and the integration is
as accurate as its sub-steps, whatever the sampling rate). The BIC of a Gaussian fit of these
residuals ranks the models.

Multiple shooting: a tumbling body's trajectory is only predictable for so many radians, so a
long record is cut into segments (each at most MAX_TURN rad of rotation) that restart from their
own fitted initial rates. Those rates are nuisance parameters of every model; an effect is
judged by what it explains inside the segments. The solver is Levenberg-Marquardt on the
arrow-shaped Jacobian (global parameters dense, each segment's three rates touching only its
own rows), eliminated segment by segment (estimation.solver); the Jacobian is taken by finite
differences, all columns of one iteration integrated in one batched call (the three rate
columns of all segments at once, since segments do not share rows).

Residual rows: the gyro samples are averaged in blocks (the model's prediction the same way)
when the sampling is much faster than the motion: the average passes the rigid-body signal
and removes vibration far above it (a rotor's 200-260 Hz), so the rows' noise is close to
white and the BIC stays honest. Samples the gyro clipped are left out; impulses at a record's
ends (a throw's release, a catch) are located from the nominal fit, trimmed and reported.

The engine's modules: data.py (the data a fit works on: rows, segments, noise level),
objective.py (a model's parameter vector, its prediction, residual, Jacobian and score),
starts.py (where the solves start), fitting.py (the solver, the rigid fit, effects added to a
fit), selection.py (the effects chosen by BIC), statistics.py (information, covariance,
intervals, independent rows), lattice.py and rounding.py (a gyro read coarser than its motion
and noise move it), residual.py (what the residual shows beyond the catalogue). This module
gathers their public names: report.py, the scripts and the tests import them from here, and a
helper process imports it before it takes fits (fitting.ENGINE).
"""

from __future__ import annotations

from inertia_gym.discrepancy.data import (
    BLOCK_MIN_RATE,
    BLOCK_RATE_PER_ROTATION,
    MAX_TURN,
    MIN_ROWS,
    MIN_SEGMENT_ROWS,
    MODAL_PHASE_PER_STEP,
    STEP_ERROR,
    TURN_PER_STEP,
    Data,
    prepare,
)
from inertia_gym.discrepancy.fitting import (
    AMBIGUOUS_DELTA_BIC,
    BUILT_IN,
    CONTINUATION_PIECES,
    CONVERGED,
    FULL_ITER,
    POLISH_DECREMENT,
    POLISH_ITER,
    POLISH_MAX_RMS,
    SCREEN_ITER,
    SHARED_CACHE,
    SIGNIFICANT_DELTA_BIC,
    START_ITER,
    STEP_FLOOR,
    fanned,
    fit_model,
    fit_nominal,
    polished,
    solve,
    solve_many,
)
from inertia_gym.discrepancy.lattice import (
    LATTICE_REPLAYS,
    LEVEL_TRIALS,
    ROUNDING_DRAWS,
    ROUNDING_RUNS,
    lattice_level,
    lattice_refits_counted,
    lattice_spread,
    rounding_runs,
)
from inertia_gym.discrepancy.objective import (
    Fit,
    Layout,
    base_inertia,
    finish,
    jacobian,
    model_inertia,
    named_params,
    objective,
    predict,
    whitened,
)
from inertia_gym.discrepancy.residual import (
    impulses,
    sparse_terms,
)
from inertia_gym.discrepancy.rounding import (
    ROUNDING_CHECK_DRAWS,
    ROUNDING_CHECK_REACH,
    rounding_checked,
    rounding_floors,
)
from inertia_gym.discrepancy.selection import (
    MAX_EFFECTS,
    REFIT_SCREENED,
    TIE_BIC,
    UNEXPLAINED_RMS,
    Explanation,
    candidates,
    claim_margin,
    fit_all,
    fit_effect,
    margin_words,
    predictive,
    predictive_selection,
    ranked,
    search,
    select,
)
from inertia_gym.discrepancy.starts import (
    CHANGE_SCAN,
    KNOTS_FOLLOW,
    KNOTS_ON_CHANGE,
    MODE_GRID,
    MODE_REACH,
    MOMENTUM_AXES,
    MOMENTUM_AXES_APART,
    NOISE_CHANGES,
    REFINE_LEVELS,
    SHORT_SEGMENTS,
    Probe,
    equation_error_phi,
    hemisphere,
    initial_rates,
)
from inertia_gym.discrepancy.statistics import (
    covariance,
    effective_share,
    information,
    intervals,
)

__all__ = [
    "AMBIGUOUS_DELTA_BIC",
    "BLOCK_MIN_RATE",
    "BLOCK_RATE_PER_ROTATION",
    "BUILT_IN",
    "CHANGE_SCAN",
    "CONTINUATION_PIECES",
    "CONVERGED",
    "Data",
    "Explanation",
    "FULL_ITER",
    "Fit",
    "KNOTS_FOLLOW",
    "KNOTS_ON_CHANGE",
    "LATTICE_REPLAYS",
    "LEVEL_TRIALS",
    "Layout",
    "MAX_EFFECTS",
    "MAX_TURN",
    "MIN_ROWS",
    "MIN_SEGMENT_ROWS",
    "MODAL_PHASE_PER_STEP",
    "MODE_GRID",
    "MODE_REACH",
    "MOMENTUM_AXES",
    "MOMENTUM_AXES_APART",
    "NOISE_CHANGES",
    "POLISH_DECREMENT",
    "POLISH_ITER",
    "POLISH_MAX_RMS",
    "Probe",
    "REFINE_LEVELS",
    "REFIT_SCREENED",
    "ROUNDING_CHECK_DRAWS",
    "ROUNDING_CHECK_REACH",
    "ROUNDING_DRAWS",
    "ROUNDING_RUNS",
    "SCREEN_ITER",
    "SHARED_CACHE",
    "SHORT_SEGMENTS",
    "SIGNIFICANT_DELTA_BIC",
    "START_ITER",
    "STEP_ERROR",
    "STEP_FLOOR",
    "TIE_BIC",
    "TURN_PER_STEP",
    "UNEXPLAINED_RMS",
    "base_inertia",
    "candidates",
    "claim_margin",
    "covariance",
    "effective_share",
    "equation_error_phi",
    "fanned",
    "finish",
    "fit_all",
    "fit_effect",
    "fit_model",
    "fit_nominal",
    "hemisphere",
    "impulses",
    "information",
    "initial_rates",
    "intervals",
    "jacobian",
    "lattice_level",
    "lattice_refits_counted",
    "lattice_spread",
    "margin_words",
    "model_inertia",
    "named_params",
    "objective",
    "polished",
    "predict",
    "predictive",
    "predictive_selection",
    "prepare",
    "ranked",
    "rounding_checked",
    "rounding_floors",
    "rounding_runs",
    "search",
    "select",
    "solve",
    "solve_many",
    "sparse_terms",
    "whitened",
]
