"""The recording as the output-error fits see it: residual rows, segments, noise level.

prepare turns a recording into Data: the gyro samples averaged in blocks where the sampling is
much faster than the motion, the record cut into segments that the fits restart from, the noise
of each row, the integration grid, and notes on what was left out. Every fit works on a Data.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.discrepancy.model import Grid, Motion, held_cumulative, integrated_attitude
from inertia_gym.errors import RecordingError
from inertia_gym.prepare import Prepared, prepared
from inertia_gym.recordings import Recording
from inertia_gym.sensors import estimate_white_noise

#: Largest rotation (rad) one segment spans; a first fit uses a quarter of it.
MAX_TURN = 20.0
#: Fewest residual rows in a segment, and in a recording diagnose accepts (3 residuals each).
MIN_SEGMENT_ROWS, MIN_ROWS = 30, 20
#: RK4 sub-steps: a mode turns at most this phase per step; the body at most the rotation whose
#: error over a segment, about (w h)^4 / 6 of the rate, stays within STEP_ERROR of the noise
#: (within these bounds, rad).
MODAL_PHASE_PER_STEP, STEP_ERROR, TURN_PER_STEP = 0.3, 0.1, (0.02, 0.3)
#: Residual rows are block means once the sampling exceeds both this rate (Hz) and this multiple
#: of the fastest rotation frequency.
BLOCK_MIN_RATE, BLOCK_RATE_PER_ROTATION = 100.0, 50.0


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
