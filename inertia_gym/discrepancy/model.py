"""The body with its effects as inputs of the compiled integrator (model_dynamics.propagate_model_batch).

One path turns a nominal inertia and a list of (effect model, parameters) into the integrator's
inputs: the truth simulator (synthetic.py) and the model that diagnose fits (fit.py) both call
it, so the physics of every effect is written once, in its class (effects/, a module per effect).

A commanded torque is carried as its running integral (N·m·s, a piecewise-linear function of
time for a torque held from each row on): actuator effects transform that function (scale,
rotation, delay), and the torque applied over each grid interval is its increment divided by
the interval's length, exact for a held torque and smooth in a delay.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from scipy.spatial.transform import Rotation

from inertia_gym.discrepancy.effects import Cumulative, EffectModel
from inertia_gym.dynamics import pack_fields
from inertia_gym.model_dynamics import propagate_model_batch


@dataclasses.dataclass(frozen=True)
class Grid:
    """The integration grid of a recording: its sample times and RK4 sub-steps between them.

    t (m+1,) s; sample_pos (n,) grid index of each sample (sample_pos[0] = 0, [-1] = m).
    """

    t: np.ndarray
    sample_pos: np.ndarray

    @classmethod
    def of(cls, t_samples, substeps) -> "Grid":
        """Grid of sample times t_samples (n,) s with substeps (n-1,) >= 1 equal steps per interval."""
        t_samples = np.asarray(t_samples, float)
        substeps = np.maximum(np.asarray(substeps, np.int64), 1)
        pos = np.concatenate([[0], np.cumsum(substeps)])
        frac = np.arange(pos[-1]) - np.repeat(pos[:-1], substeps)
        start = np.repeat(t_samples[:-1], substeps)
        step = np.repeat(np.diff(t_samples) / substeps, substeps)
        return cls(np.append(start + frac * step, t_samples[-1]), pos)

    @property
    def steps(self) -> int:
        """Grid intervals m."""
        return self.t.size - 1


def held_cumulative(t_rows, tau_rows) -> Cumulative:
    """Running integral (N·m·s) of a torque tau_rows (n, 3) N·m held from each row t_rows (n,) s
    on: zero before the first row, the last row's torque held after it.
    """
    t_rows = np.asarray(t_rows, float)
    tau_rows = np.asarray(tau_rows, float)
    knots = np.vstack([np.zeros(3), np.cumsum(tau_rows[:-1] * np.diff(t_rows)[:, None], axis=0)])

    def cumulative(t):
        t = np.atleast_1d(np.asarray(t, float))
        out = np.stack([np.interp(t, t_rows, knots[:, i], left=0.0) for i in range(3)], axis=1)
        after = t > t_rows[-1]
        out[after] = knots[-1] + tau_rows[-1] * (t[after] - t_rows[-1])[:, None]
        return out

    return cumulative


def integrated_attitude(t, rates) -> np.ndarray:
    """(k, 3, 3): the body's axes at each time t (k,) s in the frame of its axes at t[0] (the
    first the identity), integrated from its rates (k, 3) rad/s, each interval turned by the
    mean of its ends' rates.
    """
    rates = np.asarray(rates, float)
    turns = Rotation.from_rotvec(0.5 * (rates[1:] + rates[:-1]) * np.diff(t)[:, None]).as_matrix()
    rotation = np.empty((rates.shape[0], 3, 3))
    rotation[0] = np.eye(3)
    for k, turn in enumerate(turns):  # a chain: each step needs the last (k of a flight's rows)
        rotation[k + 1] = rotation[k] @ turn
    return rotation


@dataclasses.dataclass(frozen=True)
class Motion:
    """The recording's own motion on an integration grid, for a torque that the body's motion
    through the air sets (EffectModel.motion_torque): t (m+1,) s the grid, rotation (m+1, 3, 3)
    each grid point's body axes in the frame of the body at the first sample (R(t0) = I),
    integrated from the measured rates; rates (m+1, 3) rad/s the measured rates there.
    """

    t: np.ndarray
    rotation: np.ndarray
    rates: np.ndarray


@dataclasses.dataclass(frozen=True)
class Terms:
    """The integrator's inputs of one model: inertia and inertia_after (3, 3) kg·m², change_t s
    (inf: none), tau (m, 3) N·m applied over each grid interval, h (m+1, 3) kg·m²/s internal
    momentum at the grid points (known plus modelled), dist (DISTURBANCE_SIZE,) packed hook,
    damping (m,) the factor of the hook's viscous damping over each grid interval.
    """

    inertia: np.ndarray
    inertia_after: np.ndarray
    change_t: float
    tau: np.ndarray
    h: np.ndarray
    dist: np.ndarray
    damping: np.ndarray


def model_terms(inertia, effects, grid: Grid, cumulative: Cumulative | None, h_known=None,
                commanded=None, motion: Motion | None = None) -> Terms:
    """Integrator inputs of the body `inertia` (3, 3) with effects [(EffectModel, params)].

    cumulative: running integral of the commanded torque (held_cumulative), None for none;
    h_known (m+1, 3) kg·m²/s: the recording's known internal momentum on the grid, or None;
    commanded (m, 3) N·m: the command on the grid when already computed (used as is when no
    effect changes what the body receives: the same array, so simulate() passes it once);
    motion: the recording's own motion on the grid (Motion), which an effect whose torque the
    body's flight sets reads (None: no recording, and no such effect may be given).
    """
    return effect_terms(effects, grid, cumulative, h_known, commanded, motion).on(inertia)


@dataclasses.dataclass(frozen=True)
class EffectTerms:
    """The integrator's inputs that the effects set whatever the body's inertia: Terms without
    its inertias. true_inertia (3, 3) kg·m²: the inertia an effect sets (None: the body's);
    change_t s (inf: none) and change (3, 3) kg·m²: an inertia change at change_t and its size;
    tau, h, dist, damping as in Terms.
    """

    true_inertia: np.ndarray | None
    change_t: float
    change: np.ndarray | None
    tau: np.ndarray
    h: np.ndarray
    dist: np.ndarray
    damping: np.ndarray

    def on(self, inertia) -> Terms:
        """The Terms of these effects on the body `inertia` (3, 3) kg·m²."""
        inertia = np.asarray(inertia, float) if self.true_inertia is None else self.true_inertia
        after = inertia if self.change is None else inertia + self.change
        return Terms(inertia, after, self.change_t, self.tau, self.h, self.dist, self.damping)


@dataclasses.dataclass(frozen=True, eq=False)
class OwnTerms:
    """What one effect gives the integrator from its own parameters alone (None: nothing): the
    inertia it sets, its disturbance fields, an inertia change (t, size), a momentum and a
    damping factor at the grid points, and the torque the body's motion sets at the grid points.
    """

    true_inertia: np.ndarray | None
    fields: dict
    inertia_change: tuple | None
    momentum: np.ndarray | None
    damping: np.ndarray | None
    motion_torque: np.ndarray | None

    @functools.cached_property
    def packed(self) -> np.ndarray:
        """Its fields packed (pack_fields), read-only: the disturbance of every model where it
        is the only effect with fields.
        """
        out = pack_fields(self.fields)
        out.flags.writeable = False
        return out

    @staticmethod
    def of(model: EffectModel, params: dict, grid: Grid, motion: Motion | None = None) -> "OwnTerms":
        """The terms of `model` with its named `params` on the grid (motion: as in model_terms)."""
        return OwnTerms(model.true_inertia(params), model.disturbance(params), model.inertia_change(params),
                        model.momentum(params, grid.t), model.damping_factor(params, grid.t),
                        model.motion_torque(params, motion))


def effect_terms(effects, grid: Grid, cumulative: Cumulative | None, h_known=None,
                 commanded=None, motion: Motion | None = None, own=None) -> EffectTerms:
    """model_terms' inputs that do not depend on the body's inertia (the same arguments but it):
    computed once for models that differ in their inertia alone. own: each effect's OwnTerms
    where already computed (models that share an effect's parameters share them).
    """
    if own is None:
        own = [OwnTerms.of(model, params, grid, motion) for model, params in effects]
    fields: dict = {}
    change_t, change, true_inertia = np.inf, None, None
    h = h_known
    damping = _ones(grid.steps)
    moved = None  # the torques the body's motion sets, at the grid points
    for part in own:
        true = part.true_inertia
        true_inertia = true_inertia if true is None else np.asarray(true, float)
    applied = cumulative
    if h is not None:
        for model, params in effects:
            h = model.known_momentum(params, h)
    for (model, params), part in zip(effects, own):
        hook = part.fields
        clash = set(hook) & set(fields)
        if clash:
            raise ValueError(f"effects set the same disturbance term {sorted(clash)}")
        fields.update(hook)
        step = part.inertia_change
        if step is not None:
            change_t, change = float(step[0]), np.asarray(step[1], float)
        extra = part.momentum
        if extra is not None:
            h = extra if h is None else h + extra
        factor = part.damping
        if factor is not None:  # held over each interval at its mean
            damping = damping * 0.5 * (factor[1:] + factor[:-1])
        if applied is not None:
            applied = model.applied(params, applied)
        torque = part.motion_torque
        if torque is not None:
            moved = torque if moved is None else moved + torque
    if applied is None:
        tau = _zeros(grid.steps)
    elif applied is cumulative and commanded is not None:
        tau = commanded
    else:
        tau = np.diff(applied(grid.t), axis=0) / np.diff(grid.t)[:, None]
    if moved is not None:  # held over each interval at its mean, as a damping factor
        tau = tau + 0.5 * (moved[1:] + moved[:-1])
    if h is None:
        h = _zeros(grid.t.size)
    with_fields = [part for part in own if part.fields]
    dist = with_fields[0].packed if len(with_fields) == 1 else pack_fields(fields)
    return EffectTerms(true_inertia, change_t, change, tau, h, dist, damping)


@functools.lru_cache(maxsize=8)
def _zeros(rows: int) -> np.ndarray:
    """A read-only (rows, 3) array of zeros, one per size: the same object for every model
    without a torque or a momentum, so simulate() passes it once without comparing its bytes.
    """
    out = np.zeros((rows, 3))
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=8)
def _ones(steps: int) -> np.ndarray:
    """A read-only (steps,) array of ones, one per size: the damping factor of every model whose
    drag does not change in time (passed once, as _zeros).
    """
    out = np.ones(steps)
    out.flags.writeable = False
    return out


def gyro_output(effects, w, t) -> np.ndarray:
    """What the gyro reads (..., n, 3) of the true rates w (..., n, 3) at the sample times t (n,) s
    under the effects' sensor terms (leading axes: trajectories of the same model).
    """
    for model, params in effects:
        w = model.gyro(params, w, t)
    return w


def simulate(grid: Grid, seg_pos, y0, terms: list[Terms]) -> np.ndarray:
    """Integrate one trajectory per Terms (B of them) on the grid; y0 (B, S, 7) (q, w) at the
    segment starts seg_pos (S+1,) grid indices. Returns (B, n, 7) q and w at the samples.

    Equal tau, h and damping arrays are passed to the integrator once.
    """
    taus, tau_index = _unique([tm.tau for tm in terms])
    hs, h_index = _unique([tm.h for tm in terms])
    dampings, damping_index = _unique([tm.damping for tm in terms])
    return propagate_model_batch(grid.t, grid.sample_pos, seg_pos, y0,
                                 np.stack([tm.inertia for tm in terms]),
                                 np.stack([tm.inertia_after for tm in terms]),
                                 np.array([tm.change_t for tm in terms]), np.stack(taus), np.stack(hs),
                                 np.stack([tm.dist for tm in terms]), tau_index, h_index,
                                 np.stack(dampings), damping_index)


def _unique(arrays) -> tuple[list[np.ndarray], list[int]]:
    """Distinct arrays (by identity, then by value) and each input's index among them."""
    out: list[np.ndarray] = []
    seen: dict = {}
    index = []
    for a in arrays:
        key = id(a) if id(a) in seen else hash(np.ascontiguousarray(a).tobytes())
        if key not in seen:
            seen[key] = len(out)
            seen[id(a)] = seen[key]
            out.append(a)
        index.append(seen[key])
    return out, index


def unpacked(effect_models: list[EffectModel], vectors) -> list[tuple[EffectModel, dict]]:
    """[(model, named params)] of fitted vectors p, one per model."""
    return [(m, m.unpack(np.asarray(p, float))) for m, p in zip(effect_models, vectors)]
