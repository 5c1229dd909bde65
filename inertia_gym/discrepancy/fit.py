"""Fit the rigid model and the catalogue's effects to a recording by output error; rank by BIC.

The model is the truth simulator itself: the effects' own physics hooks (effects/, assembled
by model.py) integrated by dynamics.propagate_model_batch predict the gyro reading at every
sample from the body's initial rates, and a fit minimises the whitened difference from the
recorded reading (output error: no derivative of the noisy gyro enters, and the integration is
as accurate as its sub-steps, whatever the sampling rate). The BIC of a Gaussian fit of these
residuals ranks the models.

Multiple shooting: a tumbling body's trajectory is only predictable for so many radians, so a
long record is cut into segments (each at most MAX_TURN rad of rotation) that restart from their
own fitted initial rates. Those rates are nuisance parameters of every model; an effect is
judged by what it explains inside the segments. The solver is Levenberg-Marquardt on the
arrow-shaped Jacobian (global parameters dense, each segment's three rates touching only its
own rows), eliminated segment by segment (Schur complement); the Jacobian is taken by finite
differences, all columns of one iteration integrated in one batched call (the three rate
columns of all segments at once, since segments do not share rows).

Residual rows: the gyro samples are averaged in blocks (the model's prediction the same way)
when the sampling is much faster than the motion: the average passes the rigid-body signal
and removes vibration far above it (a rotor's 200-260 Hz), so the rows' noise is close to
white and the BIC stays honest. Samples the gyro clipped are left out; impulses at a record's
ends (a throw's release, a catch) are located from the nominal fit, trimmed and reported.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from scipy import signal, stats

from inertia_gym.discrepancy.effects import FLEX_BAND, REGISTRY, EffectModel, flex_floor_hz, matrix6
from inertia_gym.discrepancy.model import (
    Grid,
    Motion,
    effect_terms,
    gyro_output,
    held_cumulative,
    integrated_attitude,
    simulate,
)
from inertia_gym.discrepancy.plausibility import implausible
from inertia_gym.dynamics import skew
from inertia_gym.errors import RecordingError
from inertia_gym.estimation import solver
from inertia_gym.estimation.equation_error import (
    equation_error_theta,
    modulating_windows,
    omega_matrix,
    valid_theta,
)
from inertia_gym.estimation.inertia_param import (
    PHI_BOUND,
    inertia_from_phi,
    nearest_realizable,
    phi_from_inertia,
    realizable_face,
    realizable_phi,
)
from inertia_gym.estimation.longrun import correlation_lags
from inertia_gym.executors import fan_out, helpers_ready
from inertia_gym.information import inertia_from_theta
from inertia_gym.prepare import Prepared, end_impulses, prepared
from inertia_gym.recordings import Recording
from inertia_gym.sensors import (
    estimate_white_noise,
    lattice_replays,
    read_on_lattice,
)

SIGNIFICANT_DELTA_BIC = 10.0  # "very strong" evidence on the Kass-Raftery scale
AMBIGUOUS_DELTA_BIC = 6.0
TIE_BIC = 0.5  # BICs closer than this are a tie (the solver's own spread on equivalent models)
#: At most this many effects in a compound explanation; the best this many screens of each
#: forward step are refitted jointly.
MAX_EFFECTS, REFIT_SCREENED = 3, 3
#: Largest rotation (rad) one segment spans; a first fit uses a quarter of it.
MAX_TURN = 20.0
#: Fewest residual rows in a segment, and in a recording diagnose accepts (3 residuals each);
#: records of fewer segments than SHORT_SEGMENTS choose between starts cut into that many.
MIN_SEGMENT_ROWS, MIN_ROWS, SHORT_SEGMENTS = 30, 20, 4
#: Residual rms / noise (on some axis) over which a fit leaves the record unexplained.
UNEXPLAINED_RMS = 1.3
#: A rigid fit's continued start is polished on the record cut into these many times its own
#: segments in turn, before the record itself.
CONTINUATION_PIECES = (8, 4, 2)
#: RK4 sub-steps: a mode turns at most this phase per step; the body at most the rotation whose
#: error over a segment, about (w h)^4 / 6 of the rate, stays within STEP_ERROR of the noise
#: (within these bounds, rad).
MODAL_PHASE_PER_STEP, STEP_ERROR, TURN_PER_STEP = 0.3, 0.1, (0.02, 0.3)
#: Residual rows are block means once the sampling exceeds both this rate (Hz) and this multiple
#: of the fastest rotation frequency.
BLOCK_MIN_RATE, BLOCK_RATE_PER_ROTATION = 100.0, 50.0
#: Solver iterations: a screen, a start's trial run, a full fit; a fit stops when an iteration
#: gains less than CONVERGED in BIC units (cost gain / mean square per residual).
SCREEN_ITER, START_ITER, FULL_ITER, CONVERGED = 4, 4, 60, 1.0
#: The rigid fit (every ΔBIC's baseline) and the explanation's fit are polished on until the
#: undamped Gauss-Newton step predicts a gain under POLISH_DECREMENT in BIC units (at most
#: POLISH_ITER iterations; a step gaining under STEP_FLOOR is a stall), where their whitened
#: rms is within POLISH_MAX_RMS. On 1-s flights near the major or the middle axis the fits
#: crawl along a curved valley (the nutation fixes nearly one combination of the moments), where
#: single steps gain under CONVERGED long before the valley's floor. Stopped there (8 seeds,
#: the noise estimated from the data), the torque-free rigid fit sat 1-3 % off in the ratios,
#: its intervals missed the truth on 7 (major axis) and 3 (middle axis) of 8 seeds, and a gyro
#: scale or bias gained over 10 in BIC on 3 of the 8 clean flights near the major axis; with
#: drag, the explanation's fit sat 2-40 above its floor in cost, its intervals missing the
#: truth on 7 of 8 (major axis). A fit beyond POLISH_MAX_RMS leaves physics out: its intervals
#: are its misfit's (covariance() widens them by it), and a rigid one is only the effects'
#: start. Polished, the rigid fits of the real rotor throws with the rotor's momentum withheld
#: (hundreds of times the noise) led 3 of 20 explanations into worse fits (1 into a better),
#: and the explanations of the real racquet tosses (1.5-8 times the noise) took up to 3.5 s
#: more a toss.
POLISH_MAX_RMS = 1.5
POLISH_ITER, POLISH_DECREMENT, STEP_FLOOR = 400, 0.1, 1e-4
#: Axes searched (over a hemisphere, about 7 deg apart) for a momentum varying along one, and
#: how far apart (deg) the few kept as starts are.
MOMENTUM_AXES, MOMENTUM_AXES_APART = 200, 30.0
#: A varying momentum's knots follow its changes where the record has room for at least
#: KNOTS_FOLLOW times as many knots as the profile takes (Probe.momentum_knots): a first estimate
#: on that many times as many evenly spaced knots says where the momentum changes, and where it
#: changes beyond its noise (NOISE_CHANGES times the median change between neighbouring knots:
#: 3.4 standard deviations of a change that is noise alone), KNOTS_ON_CHANGE of the knots follow
#: that change.
KNOTS_FOLLOW, NOISE_CHANGES = 2, 5.0
#: The share of those knots that follow the change (the rest evenly spaced over the record): a
#: smooth spin-up's corners, where its curvature jumps, need knots a fraction of its length
#: apart (a wheel of 15 % of the body's momentum spinning up in 5 s of a 300-s record at 10 Hz:
#: with half, 3.6 s apart there, a second effect took up the corners in 4 of 8 cases and the
#: worst axis reached 1.59x the noise; with three quarters, 2.6 s apart, 2 of 8 and 1.18x).
KNOTS_ON_CHANGE = 0.75
#: A flexible mode's fit may move its frequency up to this factor above its fastest start; its
#: screen scans frequencies this factor apart.
MODE_REACH, MODE_GRID = 1.5, 1.15


@dataclasses.dataclass(frozen=True, eq=False)
class Data:
    """A recording prepared for the output-error fit.

    t (n,) s, w (n, 3) rad/s gyro, q (n, 4) or None measured attitude, tau (n, 3) N·m commanded
    (zeros when absent), h (n, 3) kg·m²/s known internal momentum or None; grid (Grid:
    sub-steps for the rotation; grid_for() adds those a flexible mode needs);
    seg (S+1,) sample index of each segment's start (seg[-1] = n); row (n,) residual row of each
    sample (-1: left out); row_seg (n_rows,) segment of each row; row_scale (n_rows,) noise of a
    row's mean relative to a full block's; sigma (3,) rad/s noise of a full block's mean;
    inertia0: the sidecar's nominal (3, 3) kg·m², held in every model but inertia_offset, or
    None (the inertia is then fitted in every model); scale_fixed: neither a known torque acts
    nor a known momentum that is not zero (Recording.sees_scale), so a fitted inertia's trace is
    pinned to trace0 kg·m² (the nominal's, or 1); omega_ref rad/s, j_ref kg·m², tau_ref N·m, dt s
    (median sample interval), duration s: scales for starts and step sizes; block: samples per
    row; notes: what was left out and how the noise was set (reported).
    """

    t: np.ndarray
    w: np.ndarray
    q: np.ndarray | None
    tau: np.ndarray
    h: np.ndarray | None
    grid: Grid
    seg: np.ndarray
    row: np.ndarray
    row_seg: np.ndarray
    row_scale: np.ndarray
    sigma: np.ndarray
    sigma_source: str
    has_torque: bool
    has_momentum: bool
    trace0: float
    scale_fixed: bool
    inertia0: np.ndarray | None
    omega_ref: float
    j_ref: float
    tau_ref: float
    dt: float
    duration: float
    block: int
    notes: dict
    cache: dict = dataclasses.field(default_factory=dict)
    #: Independent rows per row: 1 for white residuals; 1/tau where what the models leave out is
    #: correlated over tau rows (effective_share), so a BIC does not count them as independent.
    effective_share: float = 1.0
    #: Effect name -> what its single fit gains in BIC (rows counted as independent) from the
    #: rounding of a gyro read coarser than its motion and noise move it (rounding_floors): added
    #: to the margin an effect must clear to be claimed (claim_margin); empty elsewhere.
    rounding_floor: dict = dataclasses.field(default_factory=dict)
    #: The recording's sidecar (what it says of the sensor and the body: the plausible ranges).
    meta: dict = dataclasses.field(default_factory=dict)

    def grid_for(self, omega_mode: float = 0.0) -> Grid:
        """The integration grid for a model whose fastest mode is omega_mode rad/s (0: none):
        TURN_PER_STEP rad of rotation and MODAL_PHASE_PER_STEP of the mode per RK4 step.
        """
        per_sample = int(np.ceil(omega_mode * self.dt / MODAL_PHASE_PER_STEP))
        if per_sample <= 1:
            return self.grid
        key = ("grid", per_sample)
        if key not in self.cache:
            steps = np.maximum(np.diff(self.grid.sample_pos),
                               np.ceil(omega_mode * np.diff(self.t) / MODAL_PHASE_PER_STEP))
            self.cache[key] = Grid.of(self.t, np.clip(steps, 1, 256).astype(np.int64))
        return self.cache[key]

    def inputs(self, grid: Grid):
        """(running integral of the commanded torque or None, the command on the grid (m, 3)
        N·m or None, the known momentum on the grid (m+1, 3) kg·m²/s or None).
        """
        key = ("inputs", grid.steps)
        if key not in self.cache:
            cumulative = held_cumulative(self.t, self.tau) if self.has_torque else None
            commanded = (None if cumulative is None else
                         np.diff(cumulative(grid.t), axis=0) / np.diff(grid.t)[:, None])
            h = None if self.h is None else np.stack([np.interp(grid.t, self.t, self.h[:, i])
                                                      for i in range(3)], 1)
            self.cache[key] = (cumulative, commanded, h)
        return self.cache[key]

    def resegmented(self, count: int) -> "Data":
        """The same data cut into `count` segments (as far as each can hold MIN_SEGMENT_ROWS // 2
        rows): shorter trajectories, a wider basin for a start far from the optimum.
        """
        keep = self.row >= 0
        seg = _segments(self.t, self.w, int(keep.sum()) // self.block, MAX_TURN, MIN_SEGMENT_ROWS // 2,
                        self.block, count)
        row, row_seg, row_scale = _rows(seg, keep, self.block)
        return dataclasses.replace(self, seg=seg, row=row, row_seg=row_seg, row_scale=row_scale,
                                   cache=self.cache)

    @property
    def excited(self) -> bool:
        """The inertia's scale is seen: a known torque, or a known momentum that is not zero."""
        return not self.scale_fixed

    @property
    def n_rows(self) -> int:
        """Residual rows (each 3 axes)."""
        return self.row_seg.size

    @property
    def segments(self) -> int:
        """Segments S."""
        return self.seg.size - 1

    @property
    def t_row(self) -> np.ndarray:
        """(n_rows,) s: mean time of each row's samples."""
        keep = self.row >= 0
        return np.bincount(self.row[keep], self.t[keep]) / np.bincount(self.row[keep])

    def motion(self, grid: Grid) -> Motion:
        """The recording's own motion on grid (model.Motion): the measured rates interpolated
        to its points and the attitude integrated from them (each interval turned by its mean
        rate), relative to the first sample's.
        """
        key = ("motion", grid.steps)
        if key not in self.cache:
            rates = np.stack([np.interp(grid.t, self.t, self.w[:, i]) for i in range(3)], 1)
            self.cache[key] = Motion(grid.t, integrated_attitude(grid.t, rates), rates)
        return self.cache[key]

    def q0(self) -> np.ndarray:
        """(S, 4) attitude at each segment's start (measured, else identity)."""
        if self.q is None:
            return np.tile([1.0, 0.0, 0.0, 0.0], (self.segments, 1))
        return self.q[self.seg[:-1]]


def _segments(t, w, keep_rows, max_turn: float, min_rows: int, block: int, count: int = 0) -> np.ndarray:
    """Sample indices (S+1,) of segment starts: equal shares of the rotation angle, each at most
    max_turn rad (or `count` of them), each holding at least min_rows blocks, snapped to block
    boundaries.
    """
    n = t.size
    turn = np.concatenate([[0.0], np.cumsum(0.5 * (np.linalg.norm(w[1:], axis=1)
                                                   + np.linalg.norm(w[:-1], axis=1)) * np.diff(t))])
    count = int(min(count or np.ceil(turn[-1] / max_turn), max(1, keep_rows // min_rows)))
    if count <= 1:
        return np.array([0, n])
    cuts = np.searchsorted(turn, turn[-1] * np.arange(1, count) / count)
    cuts = np.unique(np.clip((cuts // block) * block, block, n - block))
    return np.concatenate([[0], cuts, [n]])


def _rows(seg, keep, block: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual row of each sample (-1: left out), the segment of each row and each row's
    noise scale sqrt(block / kept samples): blocks of `block` samples inside each segment.
    """
    n = keep.size
    sample_seg = np.repeat(np.arange(seg.size - 1), np.diff(seg))
    block_id = (np.arange(n) - seg[sample_seg]) // block
    key = sample_seg * (n + 1) + block_id
    key = np.where(keep, key, -1)
    used = np.unique(key[key >= 0])
    row = np.where(keep, np.searchsorted(used, key), -1)
    counts = np.bincount(row[keep], minlength=used.size)
    return row, used // (n + 1), np.sqrt(block / np.maximum(counts, 1))


def _substeps(t, w, sigma: float) -> np.ndarray:
    """RK4 steps per sample interval (n-1,) for gyro noise sigma rad/s: RK4's error over a
    segment of MAX_TURN rad is about (w h)^4 / 6 of the rate w, so the step turns the body by
    (6 STEP_ERROR sigma / |w|_max)^(1/4) rad at most (within TURN_PER_STEP).
    """
    rate = np.maximum(np.linalg.norm(w[1:], axis=1), np.linalg.norm(w[:-1], axis=1))
    top = max(float(rate.max()), 1e-12)
    turn = float(np.clip((6 * STEP_ERROR * sigma / top) ** 0.25, *TURN_PER_STEP))
    return np.clip(np.ceil(rate * np.diff(t) / turn), 1, 256).astype(np.int64)


def prepare(source: Recording | Prepared, trim: tuple[int, int] = (0, 0), max_turn: float = MAX_TURN) -> Data:
    """A record prepared for the output-error fits: blocks, segments, noise level, what is left out.

    source: the one preparation (prepare.prepared: retimed, clipped rows, end impulses, noise
    level), or a Recording, which is prepared so first. trim: samples of the prepared record
    cut at its start and end (impulses a fit's residual shows); max_turn rad per segment.
    notes["trimmed"] counts the rows left out at each end of the retimed recording, by the
    preparation and by trim together.
    """
    prep = source if isinstance(source, Prepared) else prepared(source)
    # the impulses are cut away, not masked: each segment's initial state then sits on a row the
    # fit sees, as on a record that ends there
    prep = prep.rows(int(trim[0]), prep.rec.t.size - int(trim[1]))
    rec = prep.rec
    t, w = np.asarray(rec.t, float), np.asarray(rec.w, float)
    dt = float(np.median(np.diff(t)))
    turn = float(np.median(np.linalg.norm(w, axis=1))) * dt
    if turn > np.pi:
        raise RecordingError(f"{rec.name}: the body turns {turn:.3g} rad between consecutive rows "
                             f"(median rate x median interval {dt:.3g} s): the rows are too far apart "
                             "to follow the rotation; is the time column in seconds (--time-unit)?")
    keep = prep.usable
    speed = float(np.percentile(np.linalg.norm(w, axis=1), 99))
    keep_rate = max(BLOCK_MIN_RATE, BLOCK_RATE_PER_ROTATION * speed / (2 * np.pi))
    block = max(1, int(1.0 / (dt * keep_rate)))
    seg = _segments(t, w, int(keep.sum()) // block, max_turn, MIN_SEGMENT_ROWS, block)
    row, row_seg, row_scale = _rows(seg, keep, block)
    # the step of the lattice the samples lie on (rows of one sample each: a mean of several is not)
    quantum = prep.step if block == 1 else np.zeros(3)
    left_out = (prep.kept[0], prep.total - prep.kept[1])
    notes = {"block": block, "saturated_samples": int(np.count_nonzero(~prep.usable)),
             "trimmed": [int(left_out[0]), int(left_out[1])], "segments": int(seg.size - 1),
             "quantisation_step": quantum}
    if not prep.usable.all():
        clipped = prep.saturated
        notes["saturation_rad_s"] = [float(np.abs(w[clipped[:, i], i]).min()) if clipped[:, i].any()
                                     else None for i in range(3)]
    if block == 1 and prep.sigma is not None:
        sigma, source_words = prep.sigma, "sidecar"
    else:
        means = np.stack([np.bincount(row[keep], w[keep, i]) / np.bincount(row[keep]) for i in range(3)], 1)
        sigma = np.maximum(estimate_white_noise(means if means.shape[0] > 8 else w), 1e-9)
        source_words = ("estimated from the data (differences of order 3 to 6)" if block == 1 else
                        f"estimated from the data (differences of order 3 to 6 of {block}-sample means)")
    nominal = rec.inertia_nominal
    has_momentum = rec.has_momentum
    excited = rec.sees_scale
    trace0 = float(np.trace(nominal)) if nominal is not None else 1.0
    # the body's rate, at least the gyro's noise (a body at rest: the rate the gyro can resolve)
    omega_ref = max(float(np.median(np.linalg.norm(w, axis=1))), float(sigma.mean()))
    tau = rec.tau if rec.tau is not None else np.zeros_like(w)
    duration = float(t[-1] - t[0])
    tau_max = float(np.abs(tau).max())
    tau_ref = tau_max if tau_max > 0 else trace0 / 3 * omega_ref / max(duration, dt)
    grid = Grid.of(t, _substeps(t, w, float(sigma.min() / np.sqrt(block))))
    return Data(t, w, None if rec.q is None else np.asarray(rec.q, float), tau,
                None if rec.h is None else np.asarray(rec.h, float), grid, seg, row,
                row_seg, row_scale, sigma, source_words, rec.has_torque, has_momentum, trace0,
                not excited, nominal, omega_ref, trace0 / 3, tau_ref, dt,
                duration, block, notes, meta=dict(rec.meta))


# ------------------------------------------------------------------------------------------
# Models: the parameter layout and the prediction of the gyro reading
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Layout:
    """x = [phi (6), p_1, ..., p_k, w0 (S, 3)]: the inertia (log-Cholesky, its trace pinned to
    d.trace0 when d.scale_fixed; not used when the sidecar's nominal is held), each effect's
    vector in its form, each segment's initial rates.
    """

    names: tuple[str, ...]
    forms: tuple[str, ...]
    sizes: tuple[int, ...]
    segments: int
    omega_max: float = 0.0  # rad/s: the fastest a flexible mode may be in this fit (its grid)

    @classmethod
    def of(cls, names, forms, d: Data, omega_max: float = 0.0) -> "Layout":
        """Layout of the effects `names` in `forms` on d."""
        return cls(tuple(names), tuple(forms),
                   tuple(REGISTRY[n].form_size(f, d) for n, f in zip(names, forms)), d.segments,
                   float(omega_max))

    @functools.cached_property
    def models(self) -> list[EffectModel]:
        """The effects' registered models (cached: every evaluation of the model asks them)."""
        return [REGISTRY[n] for n in self.names]

    @functools.cached_property
    def reads_through(self) -> bool:
        """Some effect changes what the gyro reads of the rates (EffectModel.gyro)."""
        return any(type(m).gyro is not EffectModel.gyro for m in self.models)

    @functools.cached_property
    def has_penalty(self) -> bool:
        """Some effect has constraint rows (EffectModel.penalty)."""
        return any(type(m).penalty is not EffectModel.penalty for m in self.models)

    @property
    def n_global(self) -> int:
        """Inertia and effect parameters."""
        return 6 + sum(self.sizes)

    @property
    def size(self) -> int:
        """Length of x."""
        return self.n_global + 3 * self.segments

    def slices(self) -> list[slice]:
        """Each effect's slice of x."""
        return self._slices

    @functools.cached_property
    def _slices(self) -> list[slice]:
        out, i = [], 6
        for s in self.sizes:
            out.append(slice(i, i + s))
            i += s
        return out

    def parts(self, x, d: "Data") -> list[tuple[EffectModel, dict]]:
        """[(model, named params)] of x; an inertia an effect sets has its trace pinned to
        d.trace0 where the scale is not seen.
        """
        return [(m, named_params(m, x[s], d)) for m, s in zip(self.models, self.slices())]

    def feasible(self, x, d: Data) -> np.ndarray:
        """The joint vector x with a fitted base inertia projected onto the inertias a body can
        have (inertia_param.realizable_phi: each principal moment at most the sum of the other
        two), and each effect's part onto what its physics allows with the model's inertia at x
        (EffectModel.feasible).
        """
        x = np.array(x, float)
        if d.inertia0 is None and not any(m.sets_inertia for m in self.models):
            x[:6] = realizable_phi(x[:6])  # the fitted inertia: only bodies that exist
        inertia = model_inertia(self, x, d)
        for m, s in zip(self.models, self.slices()):
            x[s] = m.feasible(x[s], inertia)
        return x

    def face(self, x) -> np.ndarray:
        """(m, n_global) rows of every effect's face (EffectModel.face) at x, in x's columns, and
        of the inertias' limit (realizable_face of phi = x[:6]; its rows fall outside the free
        columns where the nominal inertia is held).
        """
        limit = realizable_face(np.asarray(x[:6], float))
        rows = [np.zeros((0, self.n_global)), np.pad(limit, ((0, 0), (0, self.n_global - 6)))]
        for m, s in zip(self.models, self.slices()):
            a = m.face(np.asarray(x[s], float))
            if a.size:
                full = np.zeros((a.shape[0], self.n_global))
                full[:, s] = a
                rows.append(full)
        return np.vstack(rows)


def named_params(model: EffectModel, p, d: "Data") -> dict:
    """Model's named parameters at its part p of a joint vector: its unpack, with an inertia it
    sets pinned to d.trace0 where the scale is not seen (_pinned).
    """
    params = model.unpack(np.asarray(p, float))
    if model.sets_inertia and d.scale_fixed:
        params = {**params, "inertia": _pinned(params["inertia"], d)}
    return params


def _pinned(j, d: Data) -> np.ndarray:
    """Inertia j scaled to trace d.trace0."""
    j = np.asarray(j, float)
    return j * (d.trace0 / np.trace(j))


def base_inertia(x, d: Data) -> np.ndarray:
    """The inertia (3, 3) kg·m² of every model but inertia_offset: the sidecar's nominal where
    given, else phi = x[:6] (its trace pinned to d.trace0 when the scale is not seen).
    """
    if d.inertia0 is not None:
        return d.inertia0
    j = inertia_from_phi(np.asarray(x[:6], float))
    return _pinned(j, d) if d.scale_fixed else j


def model_inertia(layout: Layout, x, d: Data) -> np.ndarray:
    """The model's inertia (3, 3) kg·m²: an effect's (inertia_offset) where one sets it."""
    for model, params in layout.parts(x, d):
        j = model.true_inertia(params)
        if j is not None:
            return np.asarray(j, float)
    return base_inertia(x, d)


def predict(xs, layout: Layout, d: Data) -> np.ndarray:
    """(B, n, 3) rad/s: the gyro reading the model predicts at every sample, for x in xs (B, size)."""
    grid = d.grid_for(layout.omega_max if "flexible_mode" in layout.names else 0.0)
    cumulative, commanded, h_known = d.inputs(grid)
    seg_pos = np.append(grid.sample_pos[d.seg[:-1]], grid.steps)
    xs = np.asarray(xs, float)
    q0 = d.q0()
    # the segments' rates are not in the model, and the effects' terms do not depend on the
    # inertia (a Jacobian's inertia columns share them): each built once
    effect_keys = [x[6:layout.n_global].tobytes() for x in xs]
    motion = d.motion(grid) if "flight" in layout.forms else None  # what a flight's air reads
    effects: dict = {}  # effect key -> (its parts, EffectTerms, the indices of xs that have it)
    built: dict = {}  # the whole model's key -> its Terms
    terms = []
    for i, (effect_key, x) in enumerate(zip(effect_keys, xs)):
        if effect_key not in effects:
            p = layout.parts(x, d)
            effects[effect_key] = p, effect_terms(p, grid, cumulative, h_known, commanded, motion), []
        p, shared, members = effects[effect_key]
        members.append(i)
        key = x[:6].tobytes() + effect_key
        if key not in built:
            built[key] = shared.on(base_inertia(x, d))
        terms.append(built[key])
    w0 = xs[:, layout.n_global:].reshape(len(xs), -1, 3)
    y0 = np.concatenate([np.broadcast_to(q0, (len(xs), *q0.shape)), w0], axis=2)
    out = simulate(grid, seg_pos, y0, terms)[..., 4:]
    if layout.reads_through:  # the sensor's terms, applied to every trajectory of a model at once
        for p, _, members in effects.values():
            out[members] = gyro_output(p, out[members], d.t)
    return out


def _row_means(d: Data, values) -> np.ndarray:
    """(..., n, 3) per-sample values -> (..., n_rows, 3) their means over each row's samples."""
    if d.cache.get("rows", (None,))[0] is not d.row:  # (resegmented data share the cache)
        idx = np.flatnonzero(d.row >= 0)
        starts = np.flatnonzero(np.r_[True, np.diff(d.row[idx]) != 0])
        d.cache["rows"] = (d.row, idx, None if starts.size == idx.size else starts,
                           np.bincount(d.row[idx])[:, None])
    _, idx, starts, counts = d.cache["rows"]
    if starts is None:  # a sample a row: the rows are the kept samples
        return values[..., idx, :]
    return np.add.reduceat(values[..., idx, :], starts, axis=-2) / counts


def whitened(xs, layout: Layout, d: Data) -> np.ndarray:
    """(B, n_rows, 3) residual rows (predicted - measured) in units of their noise; a model that
    blew up gives non-finite rows, silently (objective and finish price them).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        diff = predict(xs, layout, d) - d.w
        return _row_means(d, diff) / (d.sigma * d.row_scale[:, None])


def _penalty_rows(x, layout: Layout, d: Data, n_res: int) -> np.ndarray:
    """The effects' constraint rows (EffectModel.penalty), weighted 1e3 sqrt(N)."""
    rows = []
    for model, s in zip(layout.models, layout.slices()):
        rows += model.penalty(np.asarray(x[s], float), d)
    return 1e3 * np.sqrt(n_res) * np.asarray(rows, float)


def objective(xs, layout: Layout, d: Data) -> np.ndarray:
    """(B, N) the least-squares vector: whitened residual rows, then any constraint rows."""
    z = whitened(xs, layout, d).reshape(len(xs), -1)
    z = np.clip(np.nan_to_num(z, nan=1e6), -1e6, 1e6)  # a model that blew up costs a lot, finitely
    if not layout.has_penalty:
        return z
    pen = [_penalty_rows(x, layout, d, z.shape[1]) for x in xs]
    return np.hstack([z, np.stack(pen)]) if pen[0].size else z


# ------------------------------------------------------------------------------------------
# The solver
# ------------------------------------------------------------------------------------------


def _steps(x, layout: Layout, d: Data) -> np.ndarray:
    """Finite-difference steps of every x entry: 1e-6 of its size or of its typical size."""
    typical = [np.ones(6)] + [m.typical(f, d) for m, f in zip(layout.models, layout.forms)]
    typical.append(np.full(3 * layout.segments, d.omega_ref))
    return 1e-6 * np.maximum(np.abs(x), np.concatenate(typical))


def jacobian(x, free, layout: Layout, d: Data, central: bool = False, r0=None):
    """Objective r0 (N,), its columns for the free global entries G (N, P) and for the segment
    rates Js (N, 3) (entry i's derivative with respect to the rates of its own segment).

    All columns come from one batched integration: one trajectory per free global entry and
    three for the rates of all segments at once (forward differences; central with central=True).
    r0: the objective at x where already known (it is then not integrated again).
    """
    points = _jacobian_points(x, free, layout, d, central)
    if r0 is None:
        r = objective(np.vstack([x[None], points]), layout, d)
        return _jacobian_columns(x, free, layout, d, r[0], r[1:], central)
    return _jacobian_columns(x, free, layout, d, r0, objective(points, layout, d), central)


def _jacobian_points(x, free, layout: Layout, d: Data, central: bool) -> np.ndarray:
    """(P + 3, size) the points jacobian() integrates besides x (2 (P + 3) with central): x with
    each free global entry moved by its step, then with every segment's rates moved along each
    axis (then the same moved the other way).
    """
    gi = np.flatnonzero(free[:layout.n_global])
    h = _steps(x, layout, d)
    plus = np.repeat(x[None], gi.size + 3, axis=0)
    plus[np.arange(gi.size), gi] += h[gi]
    seg_h = h[layout.n_global:].reshape(-1, 3)
    for c in range(3):
        plus[gi.size + c, layout.n_global + c::3] += seg_h[:, c]
    return np.vstack([plus, 2 * x - plus]) if central else plus


def _jacobian_columns(x, free, layout: Layout, d: Data, r0, rs, central: bool):
    """jacobian()'s (r0, G, Js) from the objective r0 (N,) at x and rs at its _jacobian_points."""
    gi = np.flatnonzero(free[:layout.n_global])
    h = _steps(x, layout, d)
    seg_h = h[layout.n_global:].reshape(-1, 3)
    n_plus = gi.size + 3
    hp = np.r_[h[gi], seg_h.mean(axis=0)]
    if central:
        cols = (rs[:n_plus] - rs[n_plus:]) / (2 * hp[:, None])
    else:
        cols = (rs - r0) / hp[:, None]
    # the rate columns: each entry's own segment's step (segments' steps differ)
    n_res = d.n_rows * 3
    seg_of = np.repeat(d.row_seg, 3)
    js = np.zeros((r0.size, 3))
    for c in range(3):
        js[:n_res, c] = cols[gi.size + c][:n_res] * hp[gi.size + c] / seg_h[seg_of, c]
    return r0, cols[:gi.size].T, js


def _solver_problem(free, layout: Layout, d: Data, lb, ub) -> solver.Problem:
    """The core solver's view of a model: its globals and the segments' rates, its bounds and
    each effect's physical limits (Layout.feasible) by projection, their faces (Layout.face).
    """
    return solver.Problem(n_global=layout.n_global, free=np.asarray(free[:layout.n_global], bool),
                          segments=layout.segments, locals_free=bool(free[layout.n_global:].any()),
                          project=lambda x: layout.feasible(x, d), face=layout.face, bounds=(lb, ub))


def solve(x0, free, layout: Layout, d: Data, lb, ub, max_iter: int, decrement: float | None = None):
    """The core solver (estimation/solver.py) over the free entries of x. Returns (x, cost).

    Stops when a step gains less than CONVERGED in BIC units (the cost's gain over the mean
    square per residual: N log(mse) moves by that much), or after max_iter iterations. With
    `decrement` (BIC units), every step that gains more than STEP_FLOOR counts, and the solve
    stops where the undamped Gauss-Newton step predicts a gain under `decrement` (at a physical
    limit, the lesser of that and the same step's kept on the limit's face): a polish that
    follows a curved valley to its floor.
    """
    return solve_many([x0], free, layout, d, lb, ub, max_iter, decrement)[0]


def solve_many(x0s, free, layout: Layout, d: Data, lb, ub, max_iter: int,
               decrement: float | None = None) -> list[tuple[np.ndarray, float]]:
    """[solve(x0, ...) for x0 in x0s], the solves run side by side: the points each asks for
    next (its Jacobian's, or its steps') integrated in one batch with the others'. Each
    trajectory is integrated alone, so each solve's (x, cost) is the one it gives by itself;
    the batch only saves the calls' overhead (a 1-s toss's fits spend most of their time there).
    """
    spec = _solver_problem(free, layout, d, lb, ub)
    rel = CONVERGED if decrement is None else STEP_FLOOR
    gens = [solver.levenberg_marquardt(spec, np.asarray(x0, float), max_iter, rel_tol=rel,
                                       decrement=decrement) for x0 in x0s]
    seg_of = np.full(3 * d.n_rows, -1)
    seg_of[:d.n_rows * 3] = np.repeat(d.row_seg, 3)
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
                r, g, js = _jacobian_columns(arg, free, layout, d, r0, block, False)
                sof = np.full(r.size, -1)
                sof[:seg_of.size] = seg_of
                answer = solver.Linearization(r, g, js, sof)
            try:
                asked[i] = gens[i].send(answer)
            except StopIteration as done:
                out[i] = (done.value.x, done.value.cost)
                del asked[i]
        known = fresh
    return out


# ------------------------------------------------------------------------------------------
# Fits
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Fit:
    """One fitted model: its layout, x, the whitened residual rows z (n_rows, 3), the rate
    residual rows r (n_rows, 3) rad/s, bic, k (free global parameters), inertia (3, 3) kg·m²,
    and each effect's named parameters.
    """

    layout: Layout
    x: np.ndarray
    z: np.ndarray
    r: np.ndarray
    bic: float
    k: int
    inertia: np.ndarray
    effect_params: dict  # effect name -> its named parameters, in the order the effects were added

    @property
    def names(self) -> tuple[str, ...]:
        """Its effects (() = the nominal model)."""
        return self.layout.names

    @property
    def name(self) -> str | None:
        """The last effect added (the only one of a single-effect fit), None for the nominal."""
        return self.names[-1] if self.names else None

    @property
    def forms(self) -> tuple[str, ...]:
        """The form of each effect."""
        return self.layout.forms

    @property
    def params(self) -> dict:
        """The last effect's named parameters ({} for the nominal)."""
        return self.effect_params[self.name] if self.names else {}


def _free(layout: Layout, d: Data) -> np.ndarray:
    """Bool mask over x of what the solver moves."""
    sets = any(m.sets_inertia for m in layout.models)
    phi = np.full(6, not sets and d.inertia0 is None)
    phi[0] &= not d.scale_fixed
    held = [~m.held(f, d) for m, f in zip(layout.models, layout.forms)]
    return np.concatenate([phi] + held + [np.ones(3 * layout.segments, bool)])


def _bounds(layout: Layout, d: Data):
    lo, hi = [-PHI_BOUND], [PHI_BOUND]
    for m, f in zip(layout.models, layout.forms):
        a, b = m.bounds(f, d)
        lo.append(a)
        hi.append(b)
    if "flexible_mode" in layout.names:  # the mode stays on the grid this fit integrates on
        hi[1 + layout.names.index("flexible_mode")][0] = layout.omega_max
    tail = np.full(3 * layout.segments, np.inf)
    return np.concatenate(lo + [-tail]), np.concatenate(hi + [tail])


def finish(layout: Layout, x, d: Data, k: int | None = None) -> Fit:
    """The Fit of x: residuals and BIC (k: free global parameters, counted from layout if None)."""
    if k is None:
        k = int(_free(layout, d)[:layout.n_global].sum())
    z = whitened(np.asarray(x, float)[None], layout, d)[0]
    jm = model_inertia(layout, x, d)
    n = z.size * d.effective_share
    with np.errstate(over="ignore"):
        mse = float(np.mean(z ** 2)) if np.all(np.isfinite(z)) else np.inf
    bic = n * np.log(max(mse, 1e-300)) + k * np.log(n) if np.isfinite(mse) else np.inf
    named = {m.name: params for m, params in layout.parts(x, d)}
    return Fit(layout, np.asarray(x, float), z, z * d.sigma * d.row_scale[:, None], float(bic), k, jm, named)


def initial_rates(d: Data) -> np.ndarray:
    """(S * 3,) each segment's first gyro sample: the start of its initial rates."""
    return d.w[d.seg[:-1]].ravel()


def equation_error_phi(d: Data) -> np.ndarray:
    """The phi (6,) of the linear equation-error estimate of the inertia (the nearest body that
    exists; its trace pinned to d.trace0 where the scale is not seen), from the kept samples.
    """
    kept = d.row >= 0  # clipped samples and trimmed impulses left out here too
    theta = equation_error_theta(d.t[kept], d.w[kept], d.tau[kept] if d.has_torque else None,
                                 None if d.h is None else d.h[kept], trace=d.trace0)
    return phi_from_inertia(nearest_realizable(inertia_from_theta(theta)))


def _inertia_starts(d: Data) -> list[np.ndarray]:
    """Starting phi of a fitted inertia: the sidecar's nominal (first, where given), the linear
    equation-error estimate, and on a short record (one segment) the three elongated bodies too,
    since a short flip can leave several inertias locally consistent.
    """
    out = [] if d.inertia0 is None else [phi_from_inertia(d.inertia0)]
    out.append(equation_error_phi(d))
    if d.segments == 1:
        for diag in ([1.0, 1.0, 0.1], [1.0, 0.1, 1.0], [0.1, 1.0, 1.0], [1.0, 1.0, 1.0]):
            out.append(phi_from_inertia(np.diag(diag) * d.trace0 / sum(diag)))
    return out


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
        x, _ = solve(starts[0], free, layout, d, lb, ub, FULL_ITER)
        return polished([finish(layout, x, d)], d)[0]
    if d.segments < SHORT_SEGMENTS:  # the runs are independent: side by side (fanned)
        runs = fanned(_rigid_run, d, [{"layout": layout, "starts": starts}]
                      + [{"layout": layout, "x0": x0} for x0 in starts]
                      + [{"layout": layout, "x0": starts[0], "continued": True}])
        chosen, *direct = [finish(layout, x, d) for x, _ in runs]
        chosen, best = polished([chosen, min(direct, key=lambda f: f.bic)], d)
        return best if best.bic < chosen.bic - SIGNIFICANT_DELTA_BIC else chosen
    runs = fanned(_rigid_run, d, [{"layout": layout, "x0": x0, "max_iter": START_ITER} for x0 in starts]
                  + [{"layout": layout, "x0": starts[0], "continued": True}])
    x = min(runs[:-1], key=lambda f: f[1])[0]  # the first of least cost
    x, _ = solve(x, free, layout, d, lb, ub, FULL_ITER)
    chosen, continued = polished([finish(layout, x, d), finish(layout, runs[-1][0], d)], d)
    return continued if continued.bic < chosen.bic - SIGNIFICANT_DELTA_BIC else chosen


def polished(fits: list[Fit], d: Data) -> list[Fit]:
    """The fits run on to their valley's floor (POLISH_ITER, POLISH_DECREMENT) where their
    whitened rms is within POLISH_MAX_RMS (side by side), the others as they are.
    """
    near = [i for i, f in enumerate(fits) if np.sqrt(np.mean(f.z ** 2)) <= POLISH_MAX_RMS]
    runs = fanned(_polish_run, d, [{"layout": fits[i].layout, "x0": fits[i].x} for i in near])
    out = list(fits)
    for i, x in zip(near, runs):
        out[i] = finish(fits[i].layout, x, d, fits[i].k)
    return out


def _polish_run(layout: Layout, d: Data, x0) -> np.ndarray:
    """The x of the model solved from x0 on to the valley's floor (POLISH_ITER, POLISH_DECREMENT)."""
    lb, ub = _bounds(layout, d)
    return solve(x0, _free(layout, d), layout, d, lb, ub, POLISH_ITER, POLISH_DECREMENT)[0]


def _rigid_run(layout: Layout, d: Data, x0=None, starts=None, max_iter: int = FULL_ITER,
               continued: bool = False):
    """(x, cost) of the rigid model solved for max_iter iterations from x0, or from the start
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
    stopped at 12x the noise in a basin of its own, where polished on 8 pieces, then 4, 2, 1 it
    reached the noise; on a 6-s record of the same body the rates of its 1.2-s segments taken
    from their first samples (not the last cut's) left one segment at 4000x.
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
                  POLISH_ITER, POLISH_DECREMENT)[0]
        glob = x[:lay.n_global]
        fitted = dict(zip(piece.seg[:-1].tolist(), x[lay.n_global:].reshape(-1, 3)))
    return np.r_[glob, rates(d)]


def hemisphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over a hemisphere (a Fibonacci lattice): the axes
    a sign-free direction is searched over.
    """
    k = np.arange(count) + 0.5
    z = k / count
    r = np.sqrt(1 - z ** 2)
    phi = np.pi * (1 + 5 ** 0.5) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


#: Change times scanned for an inertia change's start, and the refinements around each scan
#: peak (each at a third of the last spacing).
CHANGE_SCAN = 20
REFINE_LEVELS = 3


@dataclasses.dataclass(frozen=True)
class Probe:
    """What an effect's starts() may ask while it is added to the fit `base`: costs of the joint
    model with the base's parameters and candidate vectors of the new effect, and screens built
    on the base's residual.
    """

    layout: Layout
    d: Data
    base: Fit

    def x(self, p, inertia=None) -> np.ndarray:
        """Joint x of the base's parameters with the new effect's vector p (and the inertia
        (3, 3) instead of the base's, where the model fits one).
        """
        b = self.base
        head = b.x[:b.layout.n_global].copy()
        if inertia is not None:
            head[:6] = phi_from_inertia(inertia)
        return np.concatenate([head, p, b.x[b.layout.n_global:]])

    def own_starts(self) -> list[np.ndarray]:
        """The new effect's own starts (EffectModel.starts) as joint vectors x, each segment's
        initial rates the base's or its first gyro sample's (with_segment_rates); kept in d.cache
        for the same base on the same rows (a second search asks them again).
        """
        key = ("starts", self.layout, *_rows_and_base(self.d, self.base))
        if key not in self.d.cache:
            model, form = self.layout.models[-1], self.layout.forms[-1]
            self.d.cache[key] = self.with_segment_rates([s if s.size == self.layout.size else self.x(s)
                                                         for s in model.starts(form, self.d, self)])
        return [x.copy() for x in self.d.cache[key]]

    def with_segment_rates(self, xs) -> list[np.ndarray]:
        """Each joint x with, segment by segment, its initial rates or the segment's first gyro
        sample (initial_rates), whichever leaves that segment's rows the smaller residual.

        The base's rates were fitted without the new effect and bent to stand in for it: on a
        300-s record of five segments whose only misfit is an internal momentum, the momentum's
        equation-error start (within 2 % of the truth) with the nominal fit's rates cost 9993 in
        BIC more than no momentum at all, and the fit stalled at a gain of 821 where the truth
        gains 93324; from the first samples' rates it reaches the truth.
        """
        d, n = self.d, self.layout.n_global
        measured = [np.concatenate([x[:n], initial_rates(d)]) for x in xs]
        z = whitened(np.stack([*xs, *measured]), self.layout, d)
        z = np.clip(np.nan_to_num(z, nan=1e6), -1e6, 1e6)  # a start that blew up costs a lot, finitely
        rows = np.einsum("brk,brk->br", z, z)
        cost = np.stack([np.bincount(d.row_seg, weights=r, minlength=d.segments) for r in rows])
        out = []
        for i, x in enumerate(xs):
            take = np.repeat(cost[len(xs) + i] < cost[i], 3)
            out.append(np.concatenate([x[:n], np.where(take, measured[i][n:], x[n:])]))
        return out

    @property
    def few_segments(self) -> bool:
        """The record has few segments (each long): the cost is rough, starts matter more."""
        return self.d.segments < SHORT_SEGMENTS

    def costs(self, xs) -> np.ndarray:
        """(len(xs),) least-squares cost of each joint x."""
        r = objective(np.stack(xs), self.layout, self.d)
        return np.einsum("ij,ij->i", r, r)

    def best_x(self, xs, keep: int = 1) -> list[np.ndarray]:
        """The `keep` joint x of lowest cost."""
        return [xs[i] for i in np.argsort(self.costs(xs))[:keep]]

    def best_of(self, ps, keep: int = 1) -> list[np.ndarray]:
        """The `keep` candidate vectors p of the new effect of lowest cost (everything else the base's)."""
        return [ps[i] for i in np.argsort(self.costs([self.x(p) for p in ps]))[:keep]]

    def mode_starts(self, keep: int = 3, zeta: float = 0.03) -> list[np.ndarray]:
        """Starts of flexible_mode from a linear screen over the modal frequency.

        To first order the mode's effect on the predicted rates is linear in M = delta delta^T
        (a symmetric 3x3; what the body's motion excites) and in a = delta eta0, b = delta
        eta_dot0 / omega (what the mode's state at the start sets swinging): integrations with
        small couplings along e_i and e_i + e_j give M's six columns (polarization), three more
        with a modal displacement and three with a modal velocity (eta0 = eps, eta_dot0 = eps
        omega: as small as the coupling eps, which is sized to the body, so the probe stays
        linear on a body of any mass) a's and b's, and one least-squares solve the twelve that
        explain most at that frequency. Over a geometric
        grid of frequencies (MODE_GRID apart) in the band, then finer around the best, the `keep`
        best frequencies give delta = sqrt(lambda) v from M's leading eigenpair (size within the
        room J leaves: J - delta delta^T stays positive) or, where M has none, along a and b's
        leading direction at a fifth of that room; eta0, eta_dot0 follow from a and b along delta.
        """
        d, base = self.d, self.base
        lam_min = float(np.linalg.eigvalsh(base.inertia)[0])
        if not lam_min > 0 or d.n_rows < 16:
            return []
        lo, hi = 2 * np.pi * flex_floor_hz(d), 2 * np.pi * FLEX_BAND[1] / d.dt
        eps = np.sqrt(1e-4 * lam_min)
        directions = [np.eye(3)[i] for i in range(3)] + [np.eye(3)[i] + np.eye(3)[j]
                                                         for i, j in ((0, 1), (0, 2), (1, 2))]
        r0 = objective(self.x(np.zeros(7))[None], self.layout, self.d)[0]

        def screen(omega):
            layout = dataclasses.replace(self.layout, omega_max=omega)
            xs = [self.x(np.r_[omega, zeta, eps * v, 0.0, 0.0]) for v in directions]
            xs += [self.x(np.r_[omega, zeta, eps * e, eps, 0.0]) for e in np.eye(3)]
            xs += [self.x(np.r_[omega, zeta, eps * e, 0.0, eps * omega]) for e in np.eye(3)]
            resp = objective(np.stack(xs), layout, d) - r0
            excite = resp[:6] / eps ** 2
            cols = np.stack([excite[0], excite[1], excite[2], excite[3] - excite[0] - excite[1],
                             excite[4] - excite[0] - excite[2], excite[5] - excite[1] - excite[2]]
                            + [(resp[6 + i] - eps ** 2 * excite[i % 3]) / eps ** 2 for i in range(6)], 1)
            m = np.linalg.lstsq(cols, -r0, rcond=None)[0]
            gain = float(r0 @ r0 - np.sum((r0 + cols @ m) ** 2))
            return gain, omega, m

        grid = np.geomspace(lo, hi, max(2, int(np.log(hi / lo) / np.log(MODE_GRID)) + 1))
        scan = [screen(om) for om in grid]
        best = sorted(scan, key=lambda g: -g[0])[:keep]
        for _, om, _ in list(best):
            scan += [screen(om * f) for f in MODE_GRID ** np.linspace(-1, 1, 5)[[1, 3]]]
        out = []
        room = 0.7 * np.sqrt(lam_min)
        for gain, om, m in sorted(scan, key=lambda g: -g[0]):
            if gain <= 0 or any(abs(om - o) < 0.02 * om for o in [x[0] for x in out]):
                continue
            vals, vecs = np.linalg.eigh(matrix6(m[:6]))
            state = np.stack([m[6:9], m[9:12]], 1)  # (3, 2): a, b
            if vals[-1] > 0:
                delta = min(np.sqrt(vals[-1]), room) * vecs[:, -1]
            elif np.any(state):
                delta = 0.2 * room * np.linalg.svd(state)[0][:, 0]
            else:
                continue
            a, b = state.T @ delta / (delta @ delta)
            out.append(np.r_[om, zeta, delta, a, b * om])
            if len(out) == keep:
                break
        return out

    def change_starts(self, keep: int = 2) -> list[np.ndarray]:
        """Starts of inertia_change (joint x): over CHANGE_SCAN change times, one Gauss-Newton step from
        no change in delta_J, the segments' rates held or moved with it (everything else held;
        the rates after a change absorb part of it: moving them finds a large change's time,
        holding them a precise one); for each, the `keep` times whose steps explain most among
        the scan's local maxima, each refined REFINE_LEVELS times around itself.
        """
        d, layout = self.d, self.layout
        times = d.t_row[np.linspace(2, d.n_rows - 3, min(CHANGE_SCAN, d.n_rows - 4)).astype(int)]
        x0 = self.x(np.zeros(7))
        delta = np.arange(layout.n_global)[layout.slices()[-1]][1:]
        n_res = d.n_rows * 3
        seg_of = np.full(n_res + _penalty_rows(x0, layout, d, n_res).size, -1)
        seg_of[:n_res] = np.repeat(d.row_seg, 3)
        free = np.zeros(x0.size, bool)
        free[delta] = True
        # (change time, rates moved) -> (gain, x): the two scans share their times, so one
        # linearisation serves both and only its two steps are kept (a long record's Jacobians,
        # kept for every time scanned, took 1.5 GB at 60 000 rows)
        steps = {}

        def gauss_newton(tc, rates):
            if (tc, rates) not in steps:
                x = x0.copy()
                x[delta[0] - 1] = tc
                r, g, js = jacobian(x, free, layout, d)
                g, js = np.where(np.isfinite(g), g, 0.0), np.where(np.isfinite(js), js, 0.0)
                for moved in (True, False):
                    lin = solver.Linearization(r, g, js, seg_of)
                    dg, ds = solver.NormalBlocks.of(lin, layout.segments, moved).step(1e-9)
                    ds = ds if ds.size else np.zeros((layout.segments, 3))
                    pred = r + g @ dg
                    pred[:n_res] += np.einsum("ij,ij->i", js[:n_res], ds[seg_of[:n_res]])
                    xn = x.copy()
                    xn[delta] += dg
                    xn[layout.n_global:] += ds.ravel()
                    steps[(tc, moved)] = float(r @ r - pred @ pred), xn
            return steps[(tc, rates)]

        starts = []
        for rates in (True, False):
            scan = [gauss_newton(tc, rates) for tc in times]
            gain = np.array([g for g, _ in scan])
            padded = np.r_[-np.inf, gain, -np.inf]
            peaks = np.flatnonzero((gain >= padded[:-2]) & (gain >= padded[2:]))
            for i in peaks[np.argsort(-gain[peaks])][:keep]:
                best, span = scan[i], (times[-1] - times[0]) / max(times.size - 1, 1)
                for _ in range(REFINE_LEVELS):  # ever finer, around the best time so far
                    grid = np.clip(best[1][delta[0] - 1] + span * np.array([-2, -1, 1, 2]) / 3,
                                   times[0], times[-1])
                    best = max([best] + [gauss_newton(t, rates) for t in grid], key=lambda gs: gs[0])
                    span /= 3
                starts.append(best[1])
        return starts

    def momentum_estimate(self, tk, axes=None, with_inertia: bool = True, keep: int = 1,
                          unknowns: int | None = None) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Linear estimates (tk, H, J): at the knot times tk (K,) s (one: a constant momentum),
        an unknown internal momentum H (K, 3) kg·m²/s piecewise linear through them, and the
        inertia (3, 3) estimated with it (the base's where the nominal is held, or with_inertia is
        False). The modulating windows span a third of a turn at most, and at least 8 samples,
        and are short enough for four times as many equations as `unknowns` (default: those of
        the free three-axis form, 3K + 6).

        The integral equation error of d/dt (J w + h_known + h) + w x (J w + h_known + h) = tau
        over modulating windows is linear in theta and H (no derivative of the gyro is taken);
        an unseen scale is pinned to the trace the model uses. With `axes` (A, 3) unit vectors,
        h = axis m(t) along each in turn (linear in theta and m): the `keep` axes (at least
        MOMENTUM_AXES_APART deg apart) that explain most are returned, best first. A momentum
        changing along one fixed axis is not confused with an inertia error J w(t), which a free
        three-axis h(t) could partly absorb.
        """
        d, base = self.d, self.base
        tk = np.asarray(tk, float)
        knots = tk.size
        unknowns = 3 * knots + 6 if unknowns is None else unknowns
        span = min(2.0 / (d.omega_ref * d.dt), 3 * d.t.size // (4 * unknowns))  # 3 equations a window
        edges, phi, dphi = modulating_windows(d.t, int(max(span, 8)))
        quad = np.gradient(d.t)
        w = d.w
        known = np.zeros_like(w) if d.h is None else d.h
        fit_j = d.inertia0 is None and with_inertia
        mom = known if fit_j else w @ base.inertia.T + known
        basis = (np.stack([np.interp(d.t, tk, e) for e in np.eye(knots)], 1) if knots > 1
                 else np.ones((d.t.size, 1)))
        op = quad[:, None, None] * (-dphi[:, None, None] * np.eye(3) + phi[:, None, None] * skew(w))
        a_h = np.add.reduceat(np.einsum("nij,nk->nikj", op, basis), edges[:-1], axis=0)  # (win, 3, K, 3)
        a_j = np.add.reduceat(op @ omega_matrix(w), edges[:-1], axis=0).reshape(-1, 6) if fit_j else None
        g = -dphi[:, None] * mom + phi[:, None] * (np.cross(w, mom) - d.tau)
        rhs = -np.add.reduceat(quad[:, None] * g, edges[:-1], axis=0).ravel()

        def solve_for(a):
            """Least squares of a (..., rows, cols) theta-and-momentum against rhs, the pinned
            trace as a heavily weighted row; returns solutions (..., cols) and costs (...).
            """
            rows = a
            target = np.broadcast_to(rhs, a.shape[:-1])
            if fit_j and d.scale_fixed:  # the trace the model pins
                weight = 1e3 * (np.linalg.norm(a, axis=(-2, -1)) + 1e-300) / np.sqrt(a.shape[-1])
                pin = np.r_[1, 0, 0, 1, 0, 1, np.zeros(a.shape[-1] - 6)]
                rows = np.concatenate([a, weight[..., None, None] * pin], axis=-2)
                target = np.concatenate([target, weight[..., None] * d.trace0], axis=-1)
            col = np.linalg.norm(rows, axis=-2) + 1e-300
            scaled = rows / col[..., None, :]
            gram = np.swapaxes(scaled, -1, -2) @ scaled
            gram = gram + 1e-12 * np.einsum("...ii->...", gram)[..., None, None] * np.eye(gram.shape[-1])
            sol = np.linalg.solve(gram, (np.swapaxes(scaled, -1, -2) @ target[..., None]))[..., 0] / col
            return sol, np.sum((np.einsum("...ij,...j->...i", a, sol) - rhs) ** 2, axis=-1)

        def with_j(a):
            return np.concatenate([np.broadcast_to(a_j, a.shape[:-1] + (6,)), a], axis=-1) if fit_j else a

        def result(sol, u=None):
            tail = sol[6 if fit_j else 0:]
            hk = tail.reshape(knots, 3) if u is None else np.outer(tail, u)
            inertia = inertia_from_theta(valid_theta(sol[:6], d.trace0 if d.scale_fixed else None)) \
                if fit_j else base.inertia
            return tk, hk, inertia

        if axes is None:
            return [result(solve_for(with_j(a_h.reshape(-1, 3 * knots)))[0])]
        sols, costs = solve_for(with_j(np.einsum("wikj,aj->awik", a_h, axes).reshape(len(axes), -1, knots)))
        out, kept = [], []
        for i in np.argsort(costs):
            u = axes[i]
            if all(abs(u @ v) < np.cos(np.radians(MOMENTUM_AXES_APART)) for v in kept):
                kept.append(u)
                out.append(result(sols[i], u))
            if len(out) == keep:
                break
        return out

    def inertia_estimate(self) -> np.ndarray:
        """The phi (6,) of the record's equation-error inertia (equation_error_phi), kept in d.cache."""
        key = ("inertia_estimate", (self.d.row >= 0).tobytes())
        if key not in self.d.cache:
            self.d.cache[key] = equation_error_phi(self.d)
        return self.d.cache[key]

    def momentum_knots(self, knots: int) -> np.ndarray:
        """Knot times (knots,) s of a varying momentum's profile: evenly spaced, unless the
        record has room for KNOTS_FOLLOW times as many (EffectModel.knot_room) and the momentum
        changes somewhere beyond its noise; then a quarter of them are evenly spaced in time and
        three quarters (KNOTS_ON_CHANGE) follow that change, so that a rotor spinning up for ten
        seconds of a ten-minute record is followed through its spin-up (evenly spaced, twenty
        knots half a minute apart drew it as a slow ramp, and a gyro drift and a flexible mode
        took up the rest). Where it changes: a
        first estimate on KNOTS_FOLLOW times as many evenly spaced knots (momentum_estimate along
        the axis that explains most, in windows of a third of a turn where the record has room
        for four times as many equations as that estimate's unknowns: shorter windows left the
        spin-up of a wheel of 5 % of the body's momentum at 4-8 times the median change, longer
        at 23-31): the intervals where it changes by more than NOISE_CHANGES times the median
        change, and those beside them, are where the change's knots go, evenly spread over them.
        A smooth spin-up starts and ends below the noise of that estimate, and its corners are
        where a spline needs knots: placed in proportion to the change, they gathered where the
        spin-up is steepest, began after the start of a thrown device's 0.3-s spin-up, and a
        flexible mode took up the corner the spline could not draw (2 of 3 seeds). Neighbouring
        knots stay at least ROWS_PER_KNOT residual rows apart. Cached in d.cache
        (depends on the data and the base).
        """
        d = self.d
        even = np.linspace(d.t[0], d.t[-1], knots)
        model = REGISTRY["internal_momentum"]
        fine = KNOTS_FOLLOW * knots
        if model.knot_room(d) < fine:
            return even
        key = ("knots", knots, *_rows_and_base(d, self.base))
        if key not in d.cache:
            tf = np.linspace(d.t[0], d.t[-1], fine)
            # windows sized for the unknowns of one axis's profile (fine + 6), not three axes'
            (_, hk, _), = self.momentum_estimate(tf, hemisphere(MOMENTUM_AXES), unknowns=fine + 6)
            change = np.linalg.norm(np.diff(hk, axis=0), axis=1)
            beyond = change > NOISE_CHANGES * np.median(change)
            if not beyond.any():
                d.cache[key] = even
            else:  # the cumulative share of time and of the time it changes (KNOTS_ON_CHANGE);
                # the intervals beside those that change too, where a smooth spin-up starts and ends
                changing = np.convolve(beyond, [1, 1, 1], mode="same") > 0
                share = ((1 - KNOTS_ON_CHANGE) * (tf - tf[0]) / (tf[-1] - tf[0])
                         + KNOTS_ON_CHANGE * np.r_[0.0, np.cumsum(changing)] / changing.sum())
                placed = np.interp(np.linspace(0.0, 1.0, knots), share, tf)
                gap = model.ROWS_PER_KNOT * d.block * d.dt
                for i in range(1, knots):  # at least `gap` apart, from the start, then from the end
                    placed[i] = max(placed[i], placed[i - 1] + gap)
                placed[-1] = d.t[-1]
                for i in range(knots - 2, -1, -1):
                    placed[i] = min(placed[i], placed[i + 1] - gap)
                placed[0] = d.t[0]
                d.cache[key] = placed
        return d.cache[key]

    def momentum_starts(self, knots: int) -> list[np.ndarray]:
        """Start of internal_momentum (with the inertia estimated beside it): constant (knots 0),
        or varying along the axis, of those searched, that explains most (momentum_estimate);
        each kept only where it beats no momentum at all.
        """
        model = REGISTRY["internal_momentum"]
        starts = []
        knot_t = self.momentum_knots(knots) if knots else None
        for with_inertia in (True, False):  # the inertia estimated beside it, or the base's
            if not knots:
                (_, hk, inertia), = self.momentum_estimate(self.d.t[:1], with_inertia=with_inertia)
                starts.append(self.x(hk[0], inertia))
                continue
            for tk, hk, inertia in self.momentum_estimate(knot_t, hemisphere(MOMENTUM_AXES), with_inertia,
                                                          keep=3):
                change = hk - hk[0]
                axis = np.linalg.svd(change, full_matrices=False)[2][0]
                starts.append(self.x(model.pack({"h": hk[0], "axis": axis, "profile_t": tk,
                                                 "profile": change @ axis}), inertia))
        if knots:
            starts.append(self.x(model.pack({"h": np.zeros(3), "axis": axis, "profile_t": tk,
                                             "profile": np.zeros(knots)})))
        else:
            starts.append(self.x(np.zeros(3)))
        return self.best_x(starts, keep=len(starts))  # ranked: an estimate can be worse than none


def _rows_and_base(d: Data, base: "Fit") -> tuple:
    """What a cached fit or start (in d.cache) depends on beyond its own arguments: the rows'
    segments (resegmented data share the cache) and the fit it is added to.
    """
    return d.seg.tobytes(), base.layout, base.x.tobytes()


#: d.cache entries keyed by everything they depend on (fits and starts): what a helper may be
#: given and bring back (the others hold arrays tied to d's own objects, or a closure)
SHARED_CACHE = ("fit", "starts")


#: the catalogue as this module found it: a helper knows only these effects (an effect a user
#: registers at run time, e.g. in a script, exists in that process alone: fits run there)
BUILT_IN = dict(REGISTRY)


def _helpers() -> int:
    """Helper processes ready to take this module's fits (none where the catalogue is not
    BUILT_IN: a helper would not know the added effect).
    """
    return helpers_ready(__name__) if REGISTRY == BUILT_IN else 0


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
    if joint and len(starts) > 1 and d.segments < SHORT_SEGMENTS:
        x = _best_start_on_short_segments(starts, layout, d, lb, ub)
    else:  # the first of least cost
        x = min(solve_many([np.clip(x0, lb, ub) for x0 in starts], free, layout, d, lb, ub, first),
                key=lambda run: run[1])[0]
    if joint and first != FULL_ITER:
        x, _ = solve(x, free, layout, d, lb, ub, FULL_ITER)
    if joint:  # a start chosen elsewhere can lead astray: never worse than the effect at neutral
        neutral = probe.x(new.neutral(form, d, base))
        cost = probe.costs([x, neutral])
        if cost[1] < cost[0]:
            x = solve(neutral, free, layout, d, lb, ub, FULL_ITER)[0]
    return finish(layout, x, d, k)


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
    x, _ = solve(min(runs, key=lambda run: run[1])[0], free, lay, short, lo, hi, FULL_ITER)  # the first
    # of least cost
    first_rates = x[lay.n_global:lay.n_global + 3] if d.seg[0] == short.seg[0] else initial_rates(d)[:3]
    rates_back = np.r_[first_rates, initial_rates(d)[3:]]
    return np.r_[x[:layout.n_global], rates_back]


def candidates(d: Data) -> tuple[list[str], dict]:
    """Effects the data can test, and why the others are skipped."""
    names, skipped = [], {}
    for name, model in REGISTRY.items():
        reason = model.skip_reason(d)
        if reason is None:
            names.append(name)
        else:
            skipped[name] = reason
    return names, skipped


def fit_effect(name: str, d: Data, nominal: Fit) -> Fit:
    """One effect fitted jointly with the inertia from the nominal fit, in each of its forms;
    the form of lowest BIC. A form that nests the first (EffectModel.nested: viscous_damping's
    varying factor at 1 is its constant drag) extends it: it is fitted only where the first form
    improves the nominal's BIC by SIGNIFICANT_DELTA_BIC (a drag that changes in time, where a
    drag is seen at all), started from the first form's fit (and, on a record of few segments,
    where starts matter more, from its own starts as well).
    """
    model = REGISTRY[name]
    forms = model.forms(d)
    first = fit_model((name,), (forms[0],), d, nominal)
    fits = [first]
    span = first.layout.slices()[-1]
    for form in forms[1:]:
        inner = model.nested(form, d, first.x[span])
        if inner is None:
            fits.append(fit_model((name,), (form,), d, nominal))
        elif nominal.bic - first.bic > SIGNIFICANT_DELTA_BIC:
            extended = np.concatenate([first.x[:span.start], inner, first.x[span.stop:]])
            if d.segments < SHORT_SEGMENTS:
                fits.append(fit_model((name,), (form,), d, nominal, extra_starts=[extended]))
            else:
                fits.append(fit_model((name,), (form,), d, nominal, start=extended))
    return min(fits, key=lambda f: f.bic)


def fit_all(d: Data, nominal: Fit) -> tuple[list[Fit], dict]:
    """Every testable effect's fit (ranked by BIC, best first) and the skipped ones.

    actuator_scale is only a candidate with the trace pinned to a trusted nominal (skip_reason):
    J at the nominal trace, torque scaled by 1 + s. Exactly confounded effects (actuator_scale
    and inertia_offset: c J with c tau) tie to rounding; the tie goes to the earlier one in the
    catalogue (BICs within TIE_BIC), the report names both.
    """
    names, skipped = candidates(d)
    return ranked(fanned(fit_effect, d, [{"name": name, "nominal": nominal} for name in names])), skipped


def ranked(fits: list[Fit]) -> list[Fit]:
    """Single-effect fits best first; BICs within TIE_BIC (two solver runs of equivalent models
    differ below it) in the catalogue's order.
    """
    order = {name: i for i, name in enumerate(REGISTRY)}
    return sorted(fits, key=lambda f: (np.round(f.bic / TIE_BIC), order[f.name]))


@dataclasses.dataclass(frozen=True)
class Explanation:
    """A compound explanation: the fits of the chain nominal -> +e1 -> +e1+e2 ..., the BIC each
    effect added along that chain, and what the selection tried and left out.

    chain: fits, chain[i] holds the first i+1 effects; added: (name, delta BIC) per effect along
    the chain as selected (diagnose then polishes chain[-1], the fit it reports, and keeps these:
    the last effect's gain is not credited with the polish's); dropped: {name: reason} of effects
    removed by the backward check or never added; refused: those left out as implausible.
    """

    chain: tuple[Fit, ...]
    added: tuple[tuple[str, float], ...]
    dropped: dict
    #: {name: (why it is implausible, the BIC it would have gained)}: effects that cleared the
    #: margin but are not physics the body or its sensor plausibly has (plausibility), left out
    refused: dict = dataclasses.field(default_factory=dict)

    @property
    def fit(self) -> Fit | None:
        """The compound fit (None when no effect is selected)."""
        return self.chain[-1] if self.chain else None


def _alone(single: Fit, form: str, d: Data, nominal: Fit) -> Fit:
    """The single-effect fit of single's effect in `form`: single itself where it has that form."""
    return single if single.forms == (form,) else fit_model((single.name,), (form,), d, nominal)


def _added(nominal: Fit, chain, names) -> tuple[tuple[str, float], ...]:
    """(name, delta BIC) of each effect along chain (chain[i] holds names[:i + 1])."""
    bics = [nominal.bic] + [f.bic for f in chain]
    return tuple((n, float(bics[i] - bics[i + 1])) for i, n in enumerate(names))


def _chain(names, forms, d: Data, singles: dict) -> list[Fit]:
    """Fits of the prefixes of names, each added to the previous one (singles reused)."""
    out = [singles[names[0]]]
    for i in range(1, len(names)):
        out.append(fit_model(names[:i + 1], forms[:i + 1], d, out[-1]))
    return out


def select(d: Data, nominal: Fit, singles: list[Fit], max_effects: int = MAX_EFFECTS,
           first: Explanation | None = None) -> Explanation:
    """The compound explanation of lowest BIC of up to three searches (search): over the singles
    as fitted (each effect in its best form; `first`, where the caller has run that search), and,
    where that explanation holds an effect in a
    richer form than its simplest (internal_momentum or viscous_damping varying), over the
    singles with every effect in its simplest form and over the singles as fitted led by the
    runner-up. A rich form can soak up a second effect and lead the greedy search astray (racquet
    round 1 segment 3: the free momentum profile alone, where the varying drag and a flexible
    mode fit better by 85 with every row counted); the final explanations' BICs then decide,
    each effect an explanation claims charged the significance margin, as the forward selection
    charges it: an explanation that names one more effect must fit better by
    SIGNIFICANT_DELTA_BIC to be preferred. Ties go to the earlier search. The explanation is
    listed led by the effect that explains most alone (_led_by_best_single): the first search's
    own lead, unless the backward check dropped it or another search found the explanation.
    """
    if first is None:
        first = search(d, nominal, singles, max_effects)
    if not first.chain:
        return first
    best = first
    simplest = {n: REGISTRY[n].forms(d)[0] for n in REGISTRY}
    if any(f != simplest[n] for n, f in zip(first.fit.names, first.fit.forms)):
        plain = ranked(fanned(_alone, d, [{"single": f, "form": simplest[f.name], "nominal": nominal}
                                          for f in singles]))
        others = (search(d, nominal, plain, max_effects), search(d, nominal, singles, max_effects, lead=1))
        for other in others:
            if other.chain and _claims_cost(other.fit, d) < _claims_cost(best.fit, d) - TIE_BIC:
                best = other
    return _led_by_best_single(best, d, nominal, singles)


def _led_by_best_single(expl: Explanation, d: Data, nominal: Fit, singles: list[Fit]) -> Explanation:
    """The explanation expl with the effect that explains most alone first (of its effects, the
    one ranked first among the single-effect fits, each in its best form: the ranking the report's
    `effects` lists and the first search starts from), the others in the order the search added
    them, as a search led by the best single effect lists them; the chain's prefixes refitted in
    expl's forms to give what each adds, its compound fit kept. expl itself where it is so led.

    Ranked in their best forms, not in expl's: racquet round 1 segment 0's explanation (an
    inertia change, then a constant drag) was listed led by the inertia change, whose single fit
    beats the constant drag's, while the report's best single effect is the drag, which in its
    varying form alone explains almost three times as much (354 against 128 in BIC).
    """
    final = expl.fit
    by_name = {f.name: f for f in singles}
    rank = {f.name: i for i, f in enumerate(ranked(singles))}
    lead = min(final.names, key=rank.__getitem__)
    if lead == expl.added[0][0]:  # listed so already (its compound fit may hold them in another order)
        return expl
    alone = {n: _alone(by_name[n], form, d, nominal) for n, form in zip(final.names, final.forms)}
    order = [final.names.index(lead)] + [i for i, n in enumerate(final.names) if n != lead]
    names, forms = [final.names[i] for i in order], [final.forms[i] for i in order]
    chain = [*_chain(names[:-1], forms[:-1], d, alone), final]
    return Explanation(tuple(chain), _added(nominal, chain, names), expl.dropped, expl.refused)


def _claims_cost(fit: Fit, d: Data) -> float:
    """A compound fit's BIC plus the margin each effect it names must clear (claim_margin)."""
    return fit.bic + sum(claim_margin(d, name) for name in fit.names)


def claim_margin(d: Data, name: str) -> float:
    """The BIC an effect must gain to be claimed on d: SIGNIFICANT_DELTA_BIC, plus what its fit
    gains from the rounding of a coarsely read gyro alone (d.rounding_floor, recounted with the
    rows' independent share as every BIC is).
    """
    return SIGNIFICANT_DELTA_BIC + d.effective_share * d.rounding_floor.get(name, 0.0)


def margin_words(d: Data, name: str) -> str:
    """claim_margin in words: "10", or "10 + 335 (what the rounding alone gives it)"."""
    floor = claim_margin(d, name) - SIGNIFICANT_DELTA_BIC
    return (f"{SIGNIFICANT_DELTA_BIC:g}" if floor <= 0 else
            f"{SIGNIFICANT_DELTA_BIC:g} + {floor:.1f} (what the gyro's rounding alone gives it)")


def _screened(single: Fit, current: Fit, structured: bool, d: Data) -> Fit:
    """The effect of `single` (its single-effect fit) screened on top of the fit `current`
    (search's screen): in the form of its single-effect fit, from that fit's parameters or
    from where it changes nothing, whichever fits better, and, for an effect in a form it
    restarts_on_base in, where the residual left is `structured` (not white), from each of its own
    starts on top of current; the best screen.
    """
    name, form = single.name, single.forms[0]
    layout = Layout.of((*current.names, name), (*current.forms, form), d,
                       max(current.layout.omega_max, single.layout.omega_max))
    probe = Probe(layout, d, current)
    model = REGISTRY[name]
    starts = probe.best_x([probe.x(single.x[single.layout.slices()[0]]),
                           probe.x(model.neutral(form, d, current))])
    if form in model.restarts_on_base and structured:  # its own starts, on top of the current fit
        starts += probe.own_starts()
    screened = [fit_model(layout.names, layout.forms, d, current, joint=False, start=start,
                          omega_max=layout.omega_max) for start in starts]
    return min(screened, key=lambda f: f.bic if np.isfinite(f.bic) else np.inf)


def _without(fit: Fit, drop: int, first: Fit, d: Data) -> list[Fit]:
    """The chain of the compound fit's effects without its drop-th, each added to the previous
    (first: the single-effect fit of the first effect left, in its form in fit).
    """
    keep = [i for i in range(len(fit.names)) if i != drop]
    return _chain(tuple(fit.names[i] for i in keep), tuple(fit.forms[i] for i in keep), d,
                  {first.name: first})


def search(d: Data, nominal: Fit, singles: list[Fit], max_effects: int = MAX_EFFECTS,
           lead: int = 0) -> Explanation:
    """Forward selection over the catalogue, then a backward check.

    Step 1 takes the best single-effect fit (the lead-th best with lead > 0) if it beats the
    nominal by its claim_margin (SIGNIFICANT_DELTA_BIC, more on a coarsely rounded record).
    Each further step fits every remaining candidate's own parameters on top of the current
    fit (everything else held: a screen, started from the candidate's single-effect fit or
    from its neutral parameters, whichever fits better, and for an effect in a form it
    restarts_on_base in also, where the current fit's residual is not white (effective_share < 1),
    from each of its own starts found on top of the current fit, the best screen kept),
    refits the REFIT_SCREENED best (and any that restarts_on_base) jointly with the inertia and
    the effects already chosen,
    and keeps the best if that improves the BIC by the same margin; at most max_effects. Every
    testable effect is screened at every step, also those that explain nothing alone: a large
    effect can hide a second one. The backward check then refits without each chosen effect and
    drops any whose removal costs less than the margin, until none does. Where it dropped one,
    the forward steps resume from what is left (an effect once dropped is not screened again),
    then the backward check again, until it drops none: a rich effect taken early can be made
    redundant by those added after it, and the explanation without it may lack an effect that it
    had stood in for (Basilisk's slosh with a hidden torque: led by the varying momentum, the
    search added the inertia offset and a mode, then dropped the momentum, short of the torque).
    """
    by_name = {f.name: f for f in singles}
    ranked = [f for f in singles if np.isfinite(f.bic) and nominal.bic - f.bic > claim_margin(d, f.name)]
    dropped = {f.name: f"alone it improves the BIC by {nominal.bic - f.bic:.1f} "
                       f"<= {margin_words(d, f.name)}" if np.isfinite(f.bic) else "no valid fit"
               for f in singles if f not in ranked}
    if len(ranked) <= lead:
        return Explanation((), (), dropped)
    current = ranked[lead]
    why = implausible(current.name, current.params, d, SIGNIFICANT_DELTA_BIC)
    if why:
        refused = {current.name: (why, float(nominal.bic - current.bic))}
        return Explanation((), (), {**dropped, **_refused_words(refused)}, refused)
    chain = [current]
    pool = [f.name for f in singles if np.isfinite(f.bic)]
    removed = []  # the effects the backward checks dropped
    while True:
        current, chain, refused = _forward(d, current, chain, by_name,
                                           [n for n in pool if n not in removed], max_effects)
        current, chain, now_removed = _backward(d, nominal, current, chain, by_name, dropped)
        if not now_removed:
            break
        removed += now_removed
    chosen = current.names
    for name in pool:
        if name not in chosen and not dropped.get(name, "").startswith("removing"):
            dropped[name] = (f"alone it improves the BIC by {nominal.bic - by_name[name].bic:.1f}, "
                             f"and it adds <= {margin_words(d, name)} once "
                             f"{', '.join(chosen)} {'is' if len(chosen) == 1 else 'are'} in")
    refused = {n: r for n, r in refused.items() if n not in chosen}
    return Explanation(tuple(chain), _added(nominal, chain, chosen), {**dropped, **_refused_words(refused)},
                       refused)


def _refused_words(refused: dict) -> dict:
    """The dropped reasons of the effects left out as implausible ({name: (why, gain)})."""
    return {n: f"it would improve the BIC by {gain:.1f}, but {why}" for n, (why, gain) in refused.items()}


def _forward(d: Data, current: Fit, chain: list[Fit], by_name: dict, pool: list[str],
             max_effects: int) -> tuple[Fit, list[Fit], dict]:
    """The forward steps of `search` from the fit current (chain: its prefixes): each adds the effect of
    pool that improves the BIC most, by more than the margin; at most max_effects in all. Where
    that effect is not physics the body or its sensor plausibly has (plausibility), the steps
    stop: what is left is best fitted by something the catalogue does not plausibly hold, and a
    lesser effect that fits part of it would pad the explanation. Returns the last fit, its
    chain and the effect refused so ({name: (why, gain)}, or {}).
    """
    while len(current.names) < max_effects:
        structured = effective_share(d, current) < 1.0  # the residual left is not white
        trials = fanned(_screened, d, [{"single": by_name[n], "current": current, "structured": structured}
                                       for n in pool if n not in current.names])
        trials = [t for t in trials if np.isfinite(t.bic)]
        if not trials:
            break
        # a screen holds everything else and stops early: the leading few are refitted jointly,
        # and, where structure is left, every effect that restarts_on_base (a mode: its screen,
        # with the rates held that it trades with, says little of what it explains jointly)
        leading = sorted(trials, key=lambda t: t.bic)
        leading = leading[:REFIT_SCREENED] + [t for t in leading[REFIT_SCREENED:] if structured
                                              and t.forms[-1] in REGISTRY[t.names[-1]].restarts_on_base]
        refits = fanned(fit_model, d, [{"names": t.names, "forms": t.forms, "base": current, "start": t.x,
                                        "omega_max": t.layout.omega_max} for t in leading])
        best = min(refits, key=lambda f: f.bic)
        if not current.bic - best.bic > claim_margin(d, best.name):
            break
        # every effect of the new fit, not only the one added: two effects that trade (a bias and
        # a scale) can move an earlier one beyond what the body or its sensor plausibly has
        for name in best.names:
            why = implausible(name, best.effect_params[name], d, SIGNIFICANT_DELTA_BIC)
            if why:
                why = why if name == best.name else f"with it, `{name}` is fitted so that {why}"
                return current, chain, {best.name: (why, float(current.bic - best.bic))}
        current = best
        chain = [*chain, best]
    return current, chain, {}


def _backward(d: Data, nominal: Fit, current: Fit, chain: list[Fit], by_name: dict,
              dropped: dict) -> tuple[Fit, list[Fit], list[str]]:
    """The backward check of `search` on the fit current (chain: its prefixes): the explanation without
    each of its effects, the first whose removal costs at most the margin dropped (its reason
    written into dropped), until none is. Returns the fit left, its chain, and the names dropped.
    """
    removed = []
    changed = len(current.names) > 1
    while changed and len(current.names) > 1:
        changed = False
        # the explanation without each of its effects, in order, the first whose removal costs
        # less than the margin dropped; independent fits: as many at a time as there are
        # processes to run them (this one and the helpers ready), so that, run one after the
        # other, none is fitted that the order would skip
        removals = list(range(len(current.names)))
        while removals and not changed:
            width = 1 + _helpers()
            batch, removals = removals[:width], removals[width:]
            firsts = []  # the single fit of the first effect left without the i-th, in its form
            for i in batch:
                j = 1 if i == 0 else 0
                by_name[current.names[j]] = _alone(by_name[current.names[j]], current.forms[j], d, nominal)
                firsts.append(by_name[current.names[j]])
            without = fanned(_without, d, [{"fit": current, "drop": i, "first": first}
                                           for i, first in zip(batch, firsts)])
            for i, rest_chain in zip(batch, without):
                name = current.names[i]
                if rest_chain[-1].bic - current.bic <= claim_margin(d, name):
                    dropped[name] = (f"removing it from the explanation costs only "
                                     f"{rest_chain[-1].bic - current.bic:.1f} in BIC (backward check)")
                    current, chain, changed = rest_chain[-1], rest_chain, True
                    removed.append(name)
                    break
    return current, chain, removed


def information(fit: Fit, d: Data) -> tuple[np.ndarray, np.ndarray, float]:
    """The information of the free global entries of fit.x (the Schur complement of the
    segments' rates in J^T J, central differences), their indices, and the factor the model
    error widens the covariance by: the whitened residual's mean square where it exceeds 1,
    over the share of its rows that are independent (effective_share). Rows correlated over tau
    of them carry the information of 1/tau as many: the same count the BICs are recounted with.
    Without it, on a 1-s racquet toss with AR(1) gyro noise (coefficient 0.9 per row, stated
    level given) the shape's 95 % intervals covered the truth on 8 of 20 seeds; with it on 13
    (tests/discrepancy/test_fit.py), and white noise gives the same intervals as before.
    """
    layout = fit.layout
    free = _free(layout, d)
    r, g, js = jacobian(fit.x, free, layout, d, central=True)
    seg_of = np.full(r.size, -1)
    seg_of[:d.n_rows * 3] = np.repeat(d.row_seg, 3)
    info = g.T @ g
    has = seg_of >= 0
    starts = np.flatnonzero(np.r_[True, np.diff(seg_of[has]) != 0])
    jss, gs = js[has], g[has]
    dmat = np.add.reduceat(jss[:, :, None] * jss[:, None, :], starts, axis=0)
    bmat = np.add.reduceat(gs[:, :, None] * jss[:, None, :], starts, axis=0)
    dinv = np.linalg.pinv(dmat)
    info = info - np.einsum("spi,sij,sqj->pq", bmat, dinv, bmat)
    mse = float(np.mean(fit.z ** 2)) if np.all(np.isfinite(fit.z)) else 1.0
    return info, np.flatnonzero(free[:layout.n_global]), max(1.0, mse) / effective_share(d, fit)


def covariance(fit: Fit, d: Data) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the free global entries of fit.x and their indices: the pseudo-inverse of
    information(), widened by its model-error factor, plus, on a gyro read coarser than its
    motion and noise move it, the spread of fit's refits on its prediction read on the lattice
    (lattice_spread).
    """
    info, idx, widen = information(fit, d)
    return np.linalg.pinv(info) * widen + lattice_spread(fit, d, idx), idx


def _flat_params(model: EffectModel, p, d: Data) -> np.ndarray:
    """named_params of model at p, flattened in order into one vector."""
    return np.concatenate([np.ravel(v) for v in named_params(model, p, d).values()])


def intervals(fit: Fit, d: Data, level: float = 0.95) -> dict:
    """Two-sided intervals of every named parameter of fit's effects: {name: {param: {lo, hi}}}.

    From covariance() by the delta method through each class's named parameters as reported
    (named_params: an inertia_offset's inertia at the nominal's trace where the scale is not
    seen; through the bare unpack its intervals were at the held gauge's trace, and an
    independent audit found its 95 % interval of Ixx of zero width and off the estimate on 7 of
    7 wrong nominals); held parameters (a scanned t_change, bookkeeping) get no width from the
    fit.
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


def effective_share(d: Data, fit: Fit) -> float:
    """1/tau: the share of fit's residual rows that are independent, tau = 1 + 2 sum_l
    (1 - l/(L+1)) rho_l the integrated autocorrelation (Bartlett weights) of the whitened rows
    over the L lags they stay correlated (estimation.longrun.correlation_lags), within segments.

    White residuals give 1. A smooth misfit the catalogue does not explain (real recordings) is
    correlated over many rows: counted as independent it would make every extra parameter that
    absorbs a little of it look significant, a flexible one most of all.
    """
    z = fit.z
    if not np.all(np.isfinite(z)) or d.n_rows < 16:
        return 1.0
    pieces = [z[d.row_seg == s] for s in range(d.segments)]
    pieces = [p - p.mean(axis=0) for p in pieces if p.shape[0] >= 8]
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


#: An axis read on a lattice (sensors.quantisation_step) whose kept samples repeat in runs of this
#: many or more on average is read coarser than its motion and noise move it: its rounding error
#: is a function of the rate, not white noise, and the same at every pass of the rate through a
#: value (a torque-free tumble repeats its rates each period). Fits gain by tracing it: on a slow
#: tumble read in steps of 20 times its noise, with no effect in the data, single effects
#: improved the BIC by up to 330 and every record was explained by one to three effects.
ROUNDING_RUNS = 2.0
#: The rounded nominal models rounding_floors reads: the data's own lattice and lattices shifted
#: by random fractions of a step (what a fit gains from the rounding scatters with the lattice's
#: place: from below 0 to 740 over four shifts of one record)
ROUNDING_DRAWS = 4
#: Refits on the lattice behind a coarse gyro's share of the covariance (lattice_spread)
LATTICE_REPLAYS = 8
#: The rounded records rounding_checked reads for each effect of an explanation: its
#: refits start from the data's fits and take a fraction of a single effect's search, so enough
#: draws that their most is the 95th percentile of what the rounding gives an effect there
ROUNDING_CHECK_DRAWS = 19
#: What an effect added on top of others gains from the rounding, over the most any effect gained
#: alone (the largest single floor), beyond which rounding_checked does not look: 1.44 on the one
#: clean record where the check mattered (279 against 194, 600-s slow tumble seed 2)
ROUNDING_CHECK_REACH = 4.0


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
    a slow tumble in steps of 0.01 rad/s with noise of a quarter step read 0.0029-0.0033 rad/s
    where its samples are 0.0038 off the truth, and its clean fits were flagged unexplained at
    1.3 times that level. d itself where the level is the sidecar's or no axis is so read.
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


def rounding_floors(d: Data, nominal: Fit, names) -> dict:
    """Effect name -> the most its single fit improves the BIC (rows counted as independent) on
    records of d's rows that hold nothing but the rounding, for each effect of `names`: the
    nominal fit's own prediction with the noise beneath the step added (the level less the
    rounding's share, sqrt(sigma^2 - step^2 / 12)), rounded to the data's lattice and to
    ROUNDING_DRAWS - 1 lattices shifted by a random fraction of a step (seeded: the same record
    gets the same floors); 0 where no draw gains. {} where no axis runs ROUNDING_RUNS samples or
    more on one value (rounding that the motion or the noise scrambles from sample to sample is
    white, and the BICs already count it right).
    """
    names = list(names)
    if not names or not np.any(rounding_runs(d) >= ROUNDING_RUNS) or not np.isfinite(nominal.bic):
        return {}
    floors = dict.fromkeys(names, 0.0)
    for rounded in _rounding_records(d, nominal):
        base = fit_nominal(rounded)
        for fit in fanned(fit_effect, rounded, [{"name": name, "nominal": base} for name in names]):
            if np.isfinite(base.bic - fit.bic):
                floors[fit.name] = max(floors[fit.name], float(base.bic - fit.bic))
    return floors


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
    95 % intervals held the truth on 1 of 12 without it. The spread holds the noise's share too,
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
    return finish(layout, solve(np.clip(x0, lb, ub), _free(layout, d), layout, d, lb, ub, FULL_ITER)[0], d)


def _moved_last(fit: Fit, i: int, d: Data) -> tuple[Layout, np.ndarray]:
    """The layout and x of `fit` with its i-th effect moved to the end (the others in order)."""
    order = [j for j in range(len(fit.names)) if j != i] + [i]
    layout = Layout.of([fit.names[j] for j in order], [fit.forms[j] for j in order], d, fit.layout.omega_max)
    parts = [fit.x[fit.layout.slices()[j]] for j in order]
    return layout, np.concatenate([fit.x[:6], *parts, fit.x[fit.layout.n_global:]])


def rounding_checked(d: Data, nominal: Fit, expl: Explanation,
                     singles: list[Fit]) -> tuple[Explanation, dict]:
    """The explanation expl, each effect of it checked against what it adds where it is
    absent, on a record whose gyro rounds its samples as a function of the rate (d.rounding_floor
    set): the explanation without the effect, fitted on the data, predicts records that hold it
    and the rounding alone (_rounding_records); the explanation refitted there with and without
    the effect (from the data's fits, the effect also from where it changes nothing) gives
    what the effect gains from the rounding on top of the others (of an explanation of one
    effect: on the rigid fit's records). The first effect whose removal costs the data at most
    SIGNIFICANT_DELTA_BIC plus that gain (most over ROUNDING_CHECK_DRAWS draws, recounted with
    the rows' independent share) is dropped, until none is. The single floors price each effect
    alone, over few draws; on top of another effect the rounding can give it more (a gyro scale
    on top of a rotor's momentum on a clean slow tumble read in steps of 20x its noise: 111 in
    BIC, where alone it gained 32 against a floor of 95), and over more draws the rounding gives
    more (that momentum alone: 21 against a floor of 11 from four draws). An effect whose
    removal costs more than ROUNDING_CHECK_REACH times the largest single floor (and the margin)
    is kept unchecked, and an effect's draws stop once one drops it: the check's refits of a
    mode and a varying momentum, 19 draws each, had taken 68 s of a 111-s diagnosis where the
    largest floor was 4.3 and the effects gained 39333 and 52.

    Returns the explanation left and {name: gain} of each effect checked alone (on the rigid
    fit's records: what rounding_floors reads, over more draws; the caller raises the floors).
    """
    by_name = {f.name: f for f in singles}
    dropped = dict(expl.dropped)
    alone: dict = {}
    reach = SIGNIFICANT_DELTA_BIC + d.effective_share * ROUNDING_CHECK_REACH * max(d.rounding_floor.values(),
                                                                                  default=0.0)
    while expl.fit is not None:
        fit = expl.fit
        for i, name in enumerate(fit.names):
            j = 1 if i == 0 else 0
            rest = [] if len(fit.names) == 1 else _without(
                fit, i, _alone(by_name[fit.names[j]], fit.forms[j], d, nominal), d)
            others = rest[-1] if rest else nominal
            cost = others.bic - fit.bic
            if cost > reach:  # beyond anything the rounding gives: kept unchecked
                continue
            need = (cost - SIGNIFICANT_DELTA_BIC) / d.effective_share  # the gain that drops it
            layout, x = _moved_last(fit, i, d)
            neutral = x.copy()
            neutral[layout.slices()[-1]] = REGISTRY[name].neutral(fit.forms[i], d, others)
            gain = 0.0
            for rounded in _rounding_records(d, others, ROUNDING_CHECK_DRAWS):
                without = _refit(others.layout, others.x, rounded)
                with_it = min((_refit(layout, x0, rounded) for x0 in (x, neutral)), key=lambda f: f.bic)
                if np.isfinite(without.bic - with_it.bic):
                    gain = max(gain, float(without.bic - with_it.bic))
                if gain >= need:
                    break  # dropped whatever the other draws give
            if not rest:
                alone[name] = gain
            if gain >= need:
                dropped[name] = (f"{'removing it from the explanation' if rest else 'alone it'} improves "
                                 f"the BIC by only {cost:.1f}, where on records of the "
                                 f"{'rest of the explanation' if rest else 'rigid fit'} read through the "
                                 f"gyro's rounding alone it gains up to {d.effective_share * gain:.1f} "
                                 f"(rounding check)")
                names = [n for n in fit.names if n != name]
                expl = Explanation((), (), dropped, expl.refused) if not rest else _led_by_best_single(
                    Explanation(tuple(rest), _added(nominal, rest, names), dropped, expl.refused), d, nominal,
                    singles)
                break
        else:
            break
    return expl, alone


def impulses(d: Data, fit: Fit) -> tuple[int, int]:
    """Samples to cut at the start and the end of d (counted from its ends, clipped samples
    there included) for an impulse at either end of fit's whitened residual rows
    (:func:`end_impulses`).
    """
    start_row, stop_row = end_impulses(fit.z, d.row_seg[1:] == d.row_seg[:-1])
    kept = np.flatnonzero(d.row >= 0)
    first_sample = kept[np.r_[True, np.diff(d.row[kept]) != 0]]  # of each row
    start = int(first_sample[start_row]) if start_row else 0
    end = int(d.t.size - first_sample[stop_row]) if stop_row < d.n_rows else 0
    return start, end


def sparse_terms(d: Data, fit: Fit, threshold: float = 0.1) -> list[dict]:
    """Data-driven fallback: the torque the model misses, -J dr/dt of the rate residual rows
    (Savitzky-Golay derivative inside each segment), regressed per axis on a library of terms
    {1, w_i, w_i w_j, |w| w_i} of the measured rates by sequentially thresholded least squares.

    Returns the surviving terms per axis as {axis, term, coefficient (N·m per unit term)}.
    """
    t_row = d.t_row
    keep = d.row >= 0
    w = np.stack([np.bincount(d.row[keep], d.w[keep, i]) / np.bincount(d.row[keep]) for i in range(3)], 1)
    torque = np.zeros_like(fit.r)
    ok = np.zeros(d.n_rows, bool)
    for s in range(d.segments):
        idx = np.flatnonzero(d.row_seg == s)
        if idx.size < 7:
            continue
        step = float(np.median(np.diff(t_row[idx])))
        rate = signal.savgol_filter(fit.r[idx], 7, 2, deriv=1, delta=step, axis=0)
        torque[idx] = -rate @ fit.inertia.T
        ok[idx] = True
    if ok.sum() < 12:
        return []
    lib = {"1": np.ones(d.n_rows)}
    for i, a in enumerate("xyz"):
        lib[f"w{a}"] = w[:, i]
        lib[f"|w|w{a}"] = np.linalg.norm(w, axis=1) * w[:, i]
        for j in range(i, 3):
            lib[f"w{a}w{'xyz'[j]}"] = w[:, i] * w[:, j]
    names = list(lib)
    theta = np.stack(list(lib.values()), 1)[ok]
    scale = np.linalg.norm(theta, axis=0) + 1e-300
    a = theta / scale
    out = []
    for axis in range(3):
        y = torque[ok, axis]
        coef = np.linalg.lstsq(a, y, rcond=None)[0]
        for _ in range(10):
            small = np.abs(coef) < threshold * np.abs(coef).max()
            coef[small] = 0.0
            if (~small).any():
                coef[~small] = np.linalg.lstsq(a[:, ~small], y, rcond=None)[0]
        for name, c, s in zip(names, coef, scale):
            if c != 0.0:
                out.append({"axis": "xyz"[axis], "term": name, "coefficient": float(c / s)})
    return out
