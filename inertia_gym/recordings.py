"""Recordings: the project's CSV (+ sidecar JSON), Parquet, phyphox exports (folder, .zip, .xlsx).

A recording holds gyro samples and, optionally, attitude, commanded torque and known internal
angular momentum (docs/recording-format.md; docs/contracts.md). Columns (one row per gyro sample):

    t                    s, strictly increasing (required)
    wx, wy, wz           rad/s, body-frame gyro (required)
    qw, qx, qy, qz       body-to-inertial unit quaternion, scalar first (optional, all four)
    tau_x, tau_y, tau_z  N·m, commanded body-frame torque held from each row on (optional, all three)
    h_x, h_y, h_z        kg·m²/s, known internal angular momentum relative to the body (reaction
                         wheels, a rotor), body frame, linearly interpolated between rows
                         (optional, all three)

The body then obeys J w_dot + h_dot + w x (J w + h) = tau: a known, changing h fixes the
inertia's scale just as a known torque does. An optional group given in part (h_x, h_y without
h_z) is refused. The JSON sidecar REC.json next to REC.csv holds metadata (inertia_nominal,
gyro_sigma, quat_sigma, gyro_scale_sigma, simulation truth ...); keys it does not know
(provenance) are kept.

Every reader validates its input and raises RecordingError naming the file, row and column;
readers never write to the input. Columns named otherwise are mapped with ``columns`` (target ->
source, e.g. {"t": "time", "wx": "gx"}); units that are evidently not s and rad/s are refused
(check_units; the rule is in docs/recording-format.md) unless stated with ``time_unit`` /
``rate_unit``, which also converts them.

Gaps: where a commanded torque or a changing internal momentum is logged, a row interval over
GAP_FACTOR times the median one is a dropout, across which what the inputs did is unknown (the
format would hold the torque and interpolate h). read_recordings splits such a recording at its
gaps (split_at_gaps): each piece is a recording of its own; identify and diagnose refuse an
unsplit one (check_input_gaps). A torque-free gap is kept: the motion across it is determined.
"""

from __future__ import annotations

import csv
import dataclasses
import difflib
import json
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np

from inertia_gym.errors import ConfigError, RecordingError, SidecarKeyWarning
from inertia_gym.sensors import attitude_error, estimate_white_noise

GYRO = ("wx", "wy", "wz")
QUAT = ("qw", "qx", "qy", "qz")
TORQUE = ("tau_x", "tau_y", "tau_z")
MOMENTUM = ("h_x", "h_y", "h_z")
COLUMN_NAMES = ("t",) + GYRO + QUAT + TORQUE + MOMENTUM
PHYPHOX_COLUMNS = ("Time (s)", "Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)")
MAX_PLAUSIBLE_RATE = 200.0  # rad/s; larger gyro values almost surely are deg/s or mdps
#: rad the body may turn over a whole recording (about 160 000 revolutions: 0.1 rad/s for 115
#: days): the models integrate in steps of a tenth of a radian, so beyond this one trajectory
#: takes over 1e7 steps. Checked whatever the stated units.
MAX_TOTAL_TURN = 1e6
MIN_SAMPLES = 10
#: Time stamps are re-timed on a regular clock (retimed) when they scatter about it by at least
#: CLOCK_SCATTER_MIN of the interval (the real throws' stamps, 1-us ticks at 4 kHz, scatter
#: 0.15 %: harmless, left as they are), none is off by over CLOCK_OFFSET_MAX of it, and the gyro
#: does not fit smooth curves over the stamps better by CLOCK_KEEP_STAMPS_Z standard errors.
CLOCK_SCATTER_MIN, CLOCK_OFFSET_MAX, CLOCK_KEEP_STAMPS_Z = 5e-3, 0.45, 2.0
#: Row offsets of the four samples whose cubic interpolation_residual compares a sample with.
CUBIC_NODES = np.array([-2, -1, 1, 2])
#: A row interval longer than this many times the median one is a gap (a dropout).
GAP_FACTOR = 5.0
#: Largest magnitude accepted in any column: squares and products of such values stay finite.
MAX_MAGNITUDE = 1e100
#: Free flight found from the gyro alone (free_flight_windows): the rates' local slope is a
#: least-squares line through FLIGHT_SLOPE_ROWS samples; it may exceed the torque-free bound by
#: FLIGHT_NOISE_Z times its own noise; a flight holds at least FLIGHT_MIN_ROWS samples (what
#: identify and diagnose need) and turns the body at least FLIGHT_MIN_TURN rad (half a turn).
FLIGHT_SLOPE_ROWS, FLIGHT_NOISE_Z, FLIGHT_MIN_ROWS, FLIGHT_MIN_TURN = 5, 5.0, 20, np.pi
#: Seconds per unit of the time column, and rad/s per unit of the gyro columns.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
RATE_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0}
#: rad the body may turn between two samples at its median rate: more and no logger in seconds
#: with a rad/s gyro resolves the motion (unless the rates barely change, see below).
MAX_TURN_PER_SAMPLE = 1.0
#: Rotation per sample of real loggers (lowest plausible, typical): ranks the suspects.
TYPICAL_TURN_PER_SAMPLE = (1e-4, 0.05)
#: Relative change of the rates per radian turned below which a body that turns more than
#: MAX_TURN_PER_SAMPLE between samples is taken for a unit error: a tumbling rigid body's rates
#: change by a fair share of themselves per radian (Euler: |w_dot| ~ asymmetry * |w|^2).
MIN_RATE_CHANGE_PER_RADIAN = 0.05
#: Gyro-integrated over attitude-measured rotation beyond these bounds is a unit error.
ATTITUDE_RATIO_BOUNDS = (1.0 / 3.0, 3.0)
#: Suspected unit errors: name, factor by which it inflates the rotation per sample, the fix.
UNIT_SUSPECTS = (
    ("rates in deg/s", 180.0 / np.pi, "convert the rates to rad/s (x pi/180) or pass --rate-unit deg/s"),
    ("time in ms", 1e3, "convert t to seconds (/1000) or pass --time-unit ms"),
    ("time in us", 1e6, "convert t to seconds (/1e6) or pass --time-unit us"),
    ("time in ms and rates in deg/s", 1e3 * 180.0 / np.pi, "pass --time-unit ms --rate-unit deg/s"),
)


@dataclasses.dataclass(frozen=True)
class Recording:
    """One free-flight recording.

    Attributes
    ----------
    t : (n,) s, strictly increasing.
    w : (n, 3) rad/s, body-frame gyro.
    q : (n, 4) body-to-inertial unit quaternions (scalar first), or None.
    tau : (n, 3) N·m commanded torque held from each row on, or None.
    meta : sidecar contents (inertia_nominal, gyro_sigma, quat_sigma, effect truth ...).
    name : label for reports (file name, plus the segment for phyphox windows).
    h : (n, 3) kg·m²/s known internal angular momentum relative to the body (reaction wheels,
        a rotor), body frame, sampled like the gyro and linearly interpolated between rows,
        or None. Last so that positional construction (t, w, q, tau, meta, name) still works.

    Properties: ``has_torque`` (a non-zero commanded torque), ``has_momentum`` (h present and
    not constant: an input that changes the motion's invariants), ``sees_scale`` (a torque, or a
    known h that is not zero: either fixes the inertia's scale),
    ``inertia_nominal`` (from the sidecar).

    """

    t: np.ndarray
    w: np.ndarray
    q: np.ndarray | None = None
    tau: np.ndarray | None = None
    meta: dict = dataclasses.field(default_factory=dict)
    name: str = "recording"
    h: np.ndarray | None = None

    @property
    def has_torque(self) -> bool:
        """True when a commanded torque is present and not identically zero."""
        return self.tau is not None and bool(np.any(self.tau != 0.0))

    @property
    def has_momentum(self) -> bool:
        """True when a known internal momentum h is present and not constant over the recording."""
        return self.h is not None and bool(np.ptp(self.h, axis=0).max() > 0)

    @property
    def sees_scale(self) -> bool:
        """True when the data fix the inertia's scale: a commanded torque, or a known internal
        momentum that is not zero, constant or not (J w_dot = -w x (J w + h): scaling J without
        h changes the motion wherever h is not zero; a rotor at constant speed fixes it too).
        """
        return self.has_torque or (self.h is not None and bool(np.any(self.h != 0.0)))

    def carries(self, parts) -> bool | None:
        """Whether the body carries one of `parts` (names of BODY_PARTS): True where the
        sidecar's ``body`` says it has one (or, for a rotor, a non-zero momentum h is logged),
        False where it says it has none of them, None where it does not say.
        """
        body = self.meta.get("body") or {}
        if any(body.get(p) for p in parts) or ("rotor" in parts and self.h is not None
                                                and bool(np.any(self.h != 0.0))):
            return True
        return False if parts and all(body.get(p) is False for p in parts) else None

    @property
    def inertia_nominal(self) -> np.ndarray | None:
        """(3, 3) kg·m² from the sidecar, or None."""
        value = self.meta.get("inertia_nominal")
        return None if value is None else np.asarray(value, dtype=float)

    def rows(self, start: int, stop: int) -> "Recording":
        """The recording's rows start .. stop - 1 (the same name and sidecar)."""
        def cut(arr):
            return None if arr is None else arr[start:stop]
        return dataclasses.replace(self, t=self.t[start:stop], w=self.w[start:stop], q=cut(self.q),
                                   tau=cut(self.tau), h=cut(self.h))


def input_gaps(rec: Recording) -> np.ndarray:
    """Row indices i (k,) after which a gap begins (t[i+1] - t[i] > GAP_FACTOR x the median
    interval) while a commanded torque or a changing internal momentum is logged; () otherwise.
    """
    if rec.t.size < 3 or not (rec.has_torque or rec.has_momentum):
        return np.zeros(0, dtype=int)
    dt = np.diff(rec.t)
    return np.flatnonzero(dt > GAP_FACTOR * float(np.median(dt)))


def _inputs(rec: Recording) -> str:
    return " and ".join(name for name, present in (("commanded torque", rec.has_torque),
                                                   ("internal momentum", rec.has_momentum)) if present)


def check_input_gaps(rec: Recording) -> None:
    """Refuse (RecordingError) a recording whose logged inputs have a gap (input_gaps)."""
    gaps = input_gaps(rec)
    if gaps.size:
        i = int(gaps[0])
        raise RecordingError(
            f"{rec.name}: rows {i + 1} and {i + 2} are {rec.t[i + 1] - rec.t[i]:.4g} s apart (median "
            f"interval {float(np.median(np.diff(rec.t))):.4g} s; {gaps.size} such gap(s)) while a "
            f"{_inputs(rec)} is logged: what it did in between is unknown; split the recording at "
            "its gaps (recordings.split_at_gaps; read_recordings and the commands do)")


def split_at_gaps(rec: Recording) -> list[Recording]:
    """The pieces of rec between its input gaps (input_gaps), each a Recording named
    "NAME rows A-B" (A, B: 1-based data rows, inclusive) with the sidecar plus
    meta["split_at_gaps"] = {piece, pieces, rows: [A, B], gaps_s (the gaps' lengths), dropped_rows};
    a piece of fewer than MIN_SAMPLES rows is dropped (counted in dropped_rows). [rec] without gaps.
    """
    gaps = input_gaps(rec)
    if not gaps.size:
        return [rec]
    bounds = np.concatenate([[0], gaps + 1, [rec.t.size]])
    spans = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= MIN_SAMPLES]
    dropped = rec.t.size - sum(b - a for a, b in spans)
    if not spans:
        raise RecordingError(f"{rec.name}: {gaps.size} gap(s) in the logged {_inputs(rec)} leave no "
                             f"piece of at least {MIN_SAMPLES} rows")
    lengths = np.round(rec.t[gaps + 1] - rec.t[gaps], 6).tolist()
    return [dataclasses.replace(
        rec.rows(a, b), name=f"{rec.name} rows {a + 1}-{b}",
        meta={**rec.meta, "split_at_gaps": {"piece": k + 1, "pieces": len(spans), "rows": [a + 1, b],
                                            "gaps_s": lengths, "dropped_rows": int(dropped)}})
        for k, (a, b) in enumerate(spans)]


def regular_clock(t) -> np.ndarray | None:
    """(n,) s: the regular clock the time stamps t (n,) scatter about, by least squares on the
    clock's ticks; None where there is none to speak of: the stamps scatter by less than
    CLOCK_SCATTER_MIN of the interval (robust spread), or some stamp is over CLOCK_OFFSET_MAX
    of the interval off the clock (a drifting or paused clock is not a regular one). The ticks
    start as the row numbers (right where no sample was missed) or as the intervals' rounded
    tick counts (a missed sample skips its ticks; right while the stamps scatter by under a
    quarter of the interval), then become each stamp's nearest tick of the clock fitted to
    them, three times; the closer clock wins.
    """
    t = np.asarray(t, float)
    if t.size <= CUBIC_NODES.size:
        return None
    interval = float(np.median(np.diff(t)))
    best, best_off = None, np.inf
    for ticks in (np.arange(t.size, dtype=float),
                  np.concatenate([[0.0], np.cumsum(np.maximum(np.rint(np.diff(t) / interval), 1.0))])):
        for _ in range(3):
            slope, offset = np.polyfit(ticks, t, 1)
            ticks = np.rint((t - offset) / slope)
            if slope <= 0 or np.any(np.diff(ticks) < 1):
                break
        else:
            clock = offset + slope * ticks
            off = float(np.abs(t - clock).max())
            if off < best_off:
                best, best_off = clock, off
    if best is None or best_off > CLOCK_OFFSET_MAX * interval:
        return None
    if _robust_spread(t - best) < CLOCK_SCATTER_MIN * interval:
        return None
    return best


def _robust_spread(x) -> float:
    """The standard deviation of x (k,) from its median absolute deviation (outliers ignored)."""
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def interpolation_residual(t, w) -> np.ndarray:
    """(n - 4, 3) rad/s: by how much each interior gyro sample w (n, 3) misses the cubic through
    its two neighbours on either side, placed at the times t (n,), over the square root of
    1 + the sum of the cubic's squared weights: white gyro noise then misses by its own level
    whatever the spacing. Smaller where t says better when the samples were taken.

    Unscaled, unevenly spaced nodes amplify the noise more than even ones, and a slowly moving
    body sampled at the uneven instants its stamps record read as better fitted by an even
    clock: a clean record then placed there was read as an internal momentum (an independent
    audit's smallsat at 10 Hz, stamps right within +-30 % of the interval).
    """
    t, w = np.asarray(t, float), np.asarray(w, float)
    reach = int(CUBIC_NODES.max())
    mid = np.arange(reach, t.size - reach)
    nodes = mid[:, None] + CUBIC_NODES
    tn, at = t[nodes], t[mid]
    weights = np.ones_like(tn)
    for j in range(4):
        for m in range(4):
            if m != j:
                weights[:, j] *= (at - tn[:, m]) / (tn[:, j] - tn[:, m])
    miss = w[mid] - np.einsum("kj,kja->ka", weights, w[nodes])
    return miss / np.sqrt(1.0 + np.sum(weights ** 2, axis=1))[:, None]


def retimed(rec: Recording) -> Recording:
    """The recording with its samples on the regular clock its stamps scatter about (regular_clock),
    unless the gyro says the stamps are right: a logger that stamps each sample when software
    reads it, not when the sensor took it, scatters the stamps of a regularly sampled gyro, and
    the rate change over that scatter, and a commanded torque's edges moved by it, then look
    like physics (measured on Basilisk: stamps scattered by +-10 % of the interval had a clean
    record read as aero_drag, by +-2 % a record with bursts as internal_dissipation).
    The gyro judges by a paired test: each interior sample's squared miss of the cubic through
    its neighbours (interpolation_residual) over the clock minus over the stamps; the stamps
    are kept (rec returned as is) when that difference's mean is CLOCK_KEEP_STAMPS_Z standard
    errors above zero, i.e. the samples sit on smooth curves over their stamps clearly better
    (a sensor sampled at the irregular instants its stamps record). Otherwise, the common case
    of software stamps, the clock is taken: meta["retimed"] = {scatter_s (robust spread of the
    stamps about the clock), max_shift_s, misfit_ratio (mean square miss, clock / stamps),
    misfit_z (the paired test's statistic, negative: the clock fits better)}.
    """
    if "retimed" in rec.meta:
        return rec
    clock = regular_clock(rec.t)
    if clock is None:
        return rec
    on_clock, on_stamps = (np.sum(interpolation_residual(t, rec.w) ** 2, 1) for t in (clock, rec.t))
    diff = on_clock - on_stamps
    spread = float(np.std(diff))
    z = float(np.mean(diff) / spread * np.sqrt(diff.size)) if spread > 0 else 0.0
    if not z < CLOCK_KEEP_STAMPS_Z:
        return rec
    off = rec.t - clock
    return dataclasses.replace(rec, t=clock, meta={**rec.meta, "retimed": {
        "scatter_s": _robust_spread(off),
        "max_shift_s": float(np.abs(off).max()),
        "misfit_ratio": float(np.mean(on_clock) / max(float(np.mean(on_stamps)), 1e-300)),
        "misfit_z": z}})


def retimed_note(info: dict) -> str:
    """A sentence on a re-timing, from its record meta["retimed"] (retimed)."""
    return (f"the time stamps scatter by {info['scatter_s']:.3g} s (up to {info['max_shift_s']:.3g} s) "
            "about a regular clock, as stamps taken when software reads the sensor do; the gyro "
            f"does not say they are right (interpolation misfit {info['misfit_ratio']:.3f}x the "
            f"stamps', z = {info['misfit_z']:.1f}): the samples were placed on the clock")


def _fail(path, message, row=None, column=None) -> RecordingError:
    where = str(path)
    if row is not None:
        where += f", row {row}"
    if column is not None:
        where += f", column {column!r}"
    return RecordingError(f"{where}: {message}")


def _check_arrays(path, t, w, q, tau, labels, first_row=2, h=None, *, time_unit=None,
                  rate_unit=None) -> None:
    """Validate finiteness, time order, length and plausible units. Row numbers are file lines.

    labels maps each column name of the format (COLUMN_NAMES) to the file's own name for it.
    """
    if t.size < MIN_SAMPLES:
        raise _fail(path, f"only {t.size} samples; at least {MIN_SAMPLES} are needed")
    named = [(t[:, None], ("t",)), (w, GYRO)]
    for arr, cols in ((q, QUAT), (tau, TORQUE), (h, MOMENTUM)):
        if arr is not None:
            named.append((arr, cols))
    for arr, cols in named:
        bad = ~np.isfinite(arr)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise _fail(path, "value is NaN or infinite", first_row + r, labels[cols[c]])
        huge = np.abs(arr) > MAX_MAGNITUDE
        if huge.any():
            r, c = np.argwhere(huge)[0]
            raise _fail(path, f"value {float(arr[r, c]):.3g} is beyond any physical scale (|x| > "
                              f"{MAX_MAGNITUDE:.0e})", first_row + r, labels[cols[c]])
    with np.errstate(over="ignore", invalid="ignore"):
        dt = np.diff(t)
    if np.any(dt <= 0):
        r = int(np.argmax(dt <= 0)) + 1
        raise _fail(path, f"time does not increase ({float(t[r - 1])!r} then {float(t[r])!r})",
                    first_row + r, labels["t"])
    if not np.all(np.isfinite(dt)):
        raise _fail(path, f"time span {float(t[0])!r} to {float(t[-1])!r} overflows", column=labels["t"])
    big = np.abs(w) > MAX_PLAUSIBLE_RATE
    if rate_unit is None and big.any():
        r, c = np.argwhere(big)[0]
        raise _fail(
            path, f"gyro value {float(w[r, c]):.6g} exceeds {MAX_PLAUSIBLE_RATE} rad/s: units look like "
            "deg/s "
            "(convert to rad/s, or state the unit: --rate-unit deg/s)", first_row + r, labels[GYRO[c]],
        )
    if q is not None:
        norm = np.linalg.norm(q, axis=1)
        bad = np.abs(norm - 1.0) > 0.2
        if bad.any():
            r = int(np.argmax(bad))
            raise _fail(path, f"quaternion norm {norm[r]:.3g} is not close to 1 (units or column order?)",
                        first_row + r, labels["qw"])
        q = q / norm[:, None]
    check_units(path, t, w, q, time_unit=time_unit, rate_unit=rate_unit)
    if q is not None:
        check_attitude_frame(path, t, w, q)
    check_total_turn(path, t, w)


def check_units(path, t, w, q=None, *, time_unit=None, rate_unit=None) -> None:
    """Refuse time evidently not in seconds or rates evidently not in rad/s (RecordingError).

    t (n,) strictly increasing, w (n, 3), q (n, 4) unit quaternions or None. A unit stated
    (time_unit / rate_unit not None) is trusted; with both stated nothing is checked here. Two
    cues, each sufficient (the magnitude cue, |w| > MAX_PLAUSIBLE_RATE, is _check_arrays'):

    * attitude: with q recorded, the gyro integrated over spans in which the attitude turns
      0.2-1.5 rad must turn as far, within ATTITUDE_RATIO_BOUNDS (ms instead of s gives 1000);
    * dynamics: at its median rate the body turns more than MAX_TURN_PER_SAMPLE rad between
      samples, yet its rates change by less than MIN_RATE_CHANGE_PER_RADIAN of themselves per
      radian turned: the logger resolved the motion far more finely than the units claim.

    Scaling time by c or the rates by k scales both observations by c k, so the message names
    the suspects (UNIT_SUSPECTS) whose factor explains what was seen: for the dynamics cue the
    (at most two) that bring the turn per sample into [1e-4, 1] rad, nearest to 0.05 rad first.
    """
    suspects = [s for s in UNIT_SUSPECTS
                if (time_unit is None or "time" not in s[0]) and (rate_unit is None or "rates" not in s[0])]
    if not suspects:
        return
    keep = "; if the units are right, state them (--time-unit s --rate-unit rad/s)"
    ratio = None if q is None else _gyro_over_attitude(t, w, q)
    if ratio is not None and not ATTITUDE_RATIO_BOUNDS[0] <= ratio <= ATTITUDE_RATIO_BOUNDS[1]:
        name, factor, fix = min(suspects, key=lambda s: abs(np.log(s[1])
                                                           - np.log(np.clip(ratio, 1e-300, 1e300))))
        guess = f"{name}? {fix}" if factor / 2.0 < ratio < factor * 2.0 else \
            "check the units of t and of the gyro, and that q is this body's attitude"
        raise _fail(path, f"the gyro turns {ratio:.3g} times as far as the attitude quaternions "
                          f"do over the same spans: {guess}{keep}")
    speed = np.linalg.norm(w, axis=1)
    typical = float(np.median(speed))
    if typical <= 0.0:
        return
    with np.errstate(over="ignore"):
        turn = typical * float(np.median(np.diff(t)))
    change = float(np.median(np.linalg.norm(np.diff(w, axis=0), axis=1))) / typical
    if turn > MAX_TURN_PER_SAMPLE and change < MIN_RATE_CHANGE_PER_RADIAN * turn:
        lowest, typical_turn = TYPICAL_TURN_PER_SAMPLE
        fitting = sorted((s for s in suspects if lowest <= turn / s[1] <= MAX_TURN_PER_SAMPLE),
                         key=lambda s: abs(np.log(turn / s[1] / typical_turn)))
        guess = "; or ".join(f"{name}? {fix}" for name, _, fix in fitting[:2]) or \
            "check the units of t and of the gyro"
        raise _fail(path, f"at its median rate {typical:.3g} rad/s the body would turn {turn:.3g} rad "
                          f"between samples (median step {np.median(np.diff(t)):.3g} s), yet its rates "
                          f"change by only {change:.2g} of themselves per sample: {guess}{keep}")


def check_total_turn(path, t, w) -> None:
    """Refuse a recording over which the body turns more than MAX_TOTAL_TURN rad (the gyro's
    rate magnitude integrated over t, rad/s and s): no model can follow it in reasonable time,
    and with units stated (so check_units trusts them) it is the sign of a wrong time unit.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        speed = np.linalg.norm(w, axis=1)
        total = float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t)))
    if total > MAX_TOTAL_TURN:
        raise _fail(path, f"over its {t[-1] - t[0]:.3g} s the body would turn {total:.3g} rad at the "
                          f"gyro's rates (more than {MAX_TOTAL_TURN:.0e} rad): check the units of t and "
                          "of the gyro, or cut the recording into shorter ones")


def _attitude_lag(q) -> tuple[int, float] | None:
    """(lag, median rotation rad of the attitude over spans of lag samples), lag the first power
    of two at which it reaches 0.2 rad; None when the attitude never turns that far (too slow or
    too short to compare) or already turns more than 1.5 rad per such span (too coarse).
    """
    lag = 1
    while lag <= q.shape[0] // 4:
        dot = np.abs(np.sum(q[:-lag] * q[lag:], axis=1))
        attitude = float(np.median(2.0 * np.arccos(np.clip(dot, 0.0, 1.0))))
        if attitude >= 0.2:
            return None if attitude > 1.5 else (lag, attitude)
        lag *= 2
    return None


def _gyro_turns(t, w, lag: int) -> np.ndarray:
    """(n - lag, 3) rad: the gyro integrated over each span of lag samples (rectangle rule)."""
    with np.errstate(over="ignore", invalid="ignore"):
        steps = np.vstack([np.zeros(3), np.cumsum(w[:-1] * np.diff(t)[:, None], axis=0)])
        return steps[lag:] - steps[:-lag]


def _gyro_over_attitude(t, w, q) -> float | None:
    """Median gyro-integrated rotation over median attitude rotation across the same spans
    (_attitude_lag); None when the attitude cannot be compared.
    """
    found = _attitude_lag(q)
    if found is None:
        return None
    lag, attitude = found
    gyro = float(np.median(np.linalg.norm(_gyro_turns(t, w, lag), axis=1)))
    return gyro / attitude if np.isfinite(gyro) else np.inf


#: Multiplies a scalar-first quaternion into its conjugate (the inverse rotation).
_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])
#: How the attitude columns may have been written, as (name, fix, reading of the columns as the
#: format's (qw, qx, qy, qz) body-to-inertial quaternion).
ATTITUDE_READINGS = (
    ("as the format says (qw, qx, qy, qz; body to inertial)", "", lambda q: q),
    ("inertial to body", "negate qx, qy, qz (the format wants body to inertial)", lambda q: q * _CONJUGATE),
    ("scalar last (qx, qy, qz, qw)", "move the scalar part first (qw, qx, qy, qz)",
     lambda q: np.roll(q, 1, axis=1)),
    ("scalar last and inertial to body", "move the scalar part first and negate qx, qy, qz",
     lambda q: np.roll(q, 1, axis=1) * _CONJUGATE),
)
#: Median cosine between the attitude's body-frame rotation and the gyro's over the same spans:
#: (refused below, refused below if another reading reaches, agreeing). A wrong direction can
#: agree in part by chance (a body spinning about an axis the attitude maps near its opposite),
#: so a reading that agrees closely is preferred to the given one that agrees only roughly.
ATTITUDE_AGREEMENT = (0.8, 0.95, 0.99)


def _attitude_agreement(t, w, q, lag: int) -> float:
    """Median cosine between the body-frame rotation of q_k* q_(k+lag) (q body to inertial,
    scalar first; sensors.attitude_error) and the gyro integrated over the same span.
    """
    v = attitude_error(q[:-lag], q[lag:])
    gyro = _gyro_turns(t, w, lag)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.sum(v * gyro, axis=1) / (np.linalg.norm(v, axis=1) * np.linalg.norm(gyro, axis=1))
    cos = cos[np.isfinite(cos)]
    return float(np.median(cos)) if cos.size else 1.0


def check_attitude_frame(path, t, w, q) -> None:
    """Refuse (RecordingError) attitude quaternions that turn the body about other axes than its
    gyro does, by the median cosine of the two rotations over spans in which the attitude turns
    0.2-1.5 rad (ATTITUDE_AGREEMENT: under its first value, or under its second while another
    reading of the columns, ATTITUDE_READINGS, reaches its third), naming the reading that agrees
    where one does: scalar last, inertial to body, or both. Quiet when the attitude turns too
    little or too coarsely to compare.
    """
    found = _attitude_lag(q)
    if found is None:
        return
    agreement = [(_attitude_agreement(t, w, read(q), found[0]), name, fix)
                 for name, fix, read in ATTITUDE_READINGS]
    given = agreement[0][0]
    best, name, fix = max(agreement[1:])
    refuse, doubt, agree = ATTITUDE_AGREEMENT
    if given >= doubt or (given >= refuse and best < agree):
        return
    guess = (f"read {name} they agree ({best:.3f}): {fix}" if best >= agree else
             "no reading of the columns (scalar first or last, either direction) agrees either: "
             "is q the attitude of the gyro's body frame?")
    raise _fail(path, f"the attitude quaternions turn the body about other axes than the gyro does "
                      f"(median cosine {given:.3f} between their rotations over the same spans); {guess}")


def _apply_column_map(path, header: list[str], columns: dict | None) -> tuple[list[str], dict]:
    """The header with each mapped source column renamed to its target (columns: target ->
    source), and the labels (target -> the file's name) for messages. Unknown targets and
    sources not in the header are refused, naming them.
    """
    labels = {name: name for name in COLUMN_NAMES}
    if not columns:
        return header, labels
    unknown = [target for target in columns if target not in COLUMN_NAMES]
    if unknown:
        raise ConfigError(f"--columns: unknown column name(s) {unknown}; known: {', '.join(COLUMN_NAMES)}")
    absent = [source for source in columns.values() if source not in header]
    if absent:
        raise _fail(path, f"--columns: column(s) {absent} not in the header {header}", 1, absent[0])
    sources = list(columns.values())
    twice = sorted({s for s in sources if sources.count(s) > 1})
    if twice:
        raise ConfigError(f"--columns: column(s) {twice} mapped to more than one name")
    renamed = {source: target for target, source in columns.items()}
    # a column already carrying a mapped target's name gives way to the mapped one
    out = [renamed.get(name, f"{name} (unmapped)" if name in columns else name) for name in header]
    labels.update(columns)
    return out, labels


#: Field delimiters a CSV file may use: phyphox's five CSV exports separate by comma, tab or
#: semicolon, the last two with a decimal point or a decimal comma.
DELIMITERS = (",", "\t", ";")


def _delimiter(lines: list[str]) -> str:
    """The delimiter (DELIMITERS) of a CSV file's lines: the one that splits the header into the
    most fields, among those that split the first data line into as many (any, where none
    does); comma on a tie.
    """
    def fields(line: str, d: str) -> int:
        return len(next(csv.reader([line], delimiter=d), []))

    header = lines[0] if lines else ""
    data = next((line for line in lines[1:] if line.strip()), None)
    agree = [d for d in DELIMITERS if data is None or fields(header, d) == fields(data, d)]
    return max(agree or DELIMITERS, key=lambda d: fields(header, d))


def _read_table(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and float rows of a CSV file separated by comma, tab or semicolon (_csv_rows);
    errors name the row and column.
    """
    try:
        text = path.read_text()
    except OSError as exc:
        raise _fail(path, f"cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise _fail(path, "not a text file") from exc
    return _parse_table(text, path)


def _csv_rows(text: str) -> list[list[str]]:
    """The rows of a CSV file's text split at its delimiter (_delimiter), a byte-order mark (Excel
    writes one) dropped; where the fields are not comma separated, a decimal comma in the rows
    under the header is read as a point.
    """
    lines = text.removeprefix("\ufeff").splitlines()
    delimiter = _delimiter(lines)
    rows = list(csv.reader(lines, delimiter=delimiter))
    if delimiter == ",":
        return rows
    return rows[:1] + [[cell.replace(",", ".", 1) for cell in row] for row in rows[1:]]


def _parse_table(text: str, path) -> tuple[list[str], np.ndarray]:
    """_read_table on the text of a CSV file; path names it in errors."""
    lines = _csv_rows(text)
    if not lines or not any(cell.strip() for cell in lines[0]):
        raise _fail(path, "empty file (a header row is required)", 1)
    header = [cell.strip() for cell in lines[0]]
    rows = []
    for i, row in enumerate(lines[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise _fail(path, f"{len(row)} fields, the header has {len(header)}", i)
        values = []
        for name, cell in zip(header, row):
            try:
                values.append(float(cell))
            except ValueError:
                raise _fail(path, f"not a number: {cell!r}", i, name) from None
        rows.append(values)
    if not rows:
        raise _fail(path, "no data rows after the header", 2)
    return header, np.asarray(rows, dtype=float)


def _columns(path, header, data, names, required, label=None):
    """(n, len(names)) columns, or None when an optional group is absent; a partial group fails."""
    missing = [n for n in names if n not in header]
    if missing and (required or len(missing) < len(names)):
        what = "" if required or label is None else \
            f"{label} given in part ({', '.join(names)} go together): "
        hint = f" (map the file's names with --columns {missing[0]}=NAME,...)" if required else ""
        raise _fail(path, f"{what}missing column(s) {missing}; the header is {header}{hint}", 1, missing[0])
    if missing:
        return None
    return np.stack([data[:, header.index(n)] for n in names], axis=1)


#: The sidecar keys the tool reads, and those its own simulators write (the truth of a synthetic
#: record). Any other key is the user's provenance and passes untouched.
SIDECAR_KEYS = ("inertia_nominal", "gyro_sigma", "quat_sigma", "gyro_scale_sigma", "gyro_full_scale_rad_s",
                "gyro_bias_max", "body", "effect", "effects", "rotor", "seed", "basilisk_truth")
#: The parts a sidecar's ``body`` object may say the body has (true) or lacks (false): a rotor or
#: wheel, flexible appendages, liquid propellant. diagnose names an effect that needs one of
#: them as that physics only where the body may carry it.
BODY_PARTS = ("rotor", "appendages", "propellant")
#: An unknown key this similar to a known one (difflib's ratio 2M/T: one or two characters mistyped,
#: dropped or swapped in a key of ten or more) is taken for a typo of it; the provenance keys of
#: real sidecars (gyro_sigma_static, gyro_quantum_rad_s, sample_dt, ...) score under 0.75.
TYPO_SIMILARITY = 0.8


def _warn_typos(meta: dict, side: Path) -> None:
    """One SidecarKeyWarning per key of meta that is not a known key but resembles one."""
    for key in meta:
        if key in SIDECAR_KEYS:
            continue
        near = difflib.get_close_matches(str(key), SIDECAR_KEYS, n=1, cutoff=TYPO_SIMILARITY)
        if near:
            warnings.warn(f"{side}: sidecar key {key!r} is not one the tool reads; did you mean "
                          f"{near[0]!r}? The run goes on without it.", SidecarKeyWarning, stacklevel=3)


def read_sidecar(csv_path: Path) -> dict:
    """The JSON sidecar next to a recording (REC.json for REC.csv), or {} if absent. A key that
    looks like a mistyped known key gets a SidecarKeyWarning naming the key it resembles; other
    unknown keys are provenance, kept as they are.
    """
    side = Path(csv_path).with_suffix(".json")
    if not side.exists():
        return {}
    try:
        meta = json.loads(side.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise _fail(side, f"invalid JSON sidecar: {exc}") from exc
    if not isinstance(meta, dict):
        raise _fail(side, "the sidecar must be a JSON object")
    _warn_typos(meta, side)
    if "inertia_nominal" in meta:
        j = np.asarray(meta["inertia_nominal"], dtype=float) if _is_numeric(meta["inertia_nominal"]) else None
        if j is None or j.shape != (3, 3) or not np.all(np.isfinite(j)) or not np.allclose(j, j.T) \
                or np.linalg.eigvalsh(j).min() <= 0:
            raise _fail(side, "inertia_nominal must be a symmetric positive-definite 3x3 matrix",
                        column="inertia_nominal")
    for key in ("gyro_sigma", "quat_sigma", "gyro_bias_max"):
        if key in meta and not (isinstance(meta[key], (int, float)) and meta[key] > 0):
            raise _fail(side, f"{key} must be a positive number, got {meta[key]!r}", column=key)
    body = meta.get("body")
    if body is not None and not (isinstance(body, dict) and set(body) <= set(BODY_PARTS)
                                 and all(isinstance(v, bool) for v in body.values())):
        raise _fail(side, f"body must be an object whose keys are among {list(BODY_PARTS)}, each true "
                          f"(the body has it) or false (it has none), got {body!r}", column="body")
    scale = meta.get("gyro_scale_sigma")
    if scale is not None and not (isinstance(scale, (int, float)) and 0 <= scale < 1):
        raise _fail(side, f"gyro_scale_sigma (the gyro scale factor's relative 1-sigma uncertainty) must "
                          f"be a number in [0, 1), got {scale!r}", column="gyro_scale_sigma")
    return meta


def _is_numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def read_csv_recording(path: str | Path, columns: dict | None = None, time_unit: str | None = None,
                       rate_unit: str | None = None) -> Recording:
    """Read the project's CSV format (docs/recording-format.md) and its sidecar.

    columns, time_unit, rate_unit: as for read_recordings.
    """
    path = Path(path)
    header, data = _read_table(path)
    return _from_columns(path, header, data, read_sidecar(path), columns, time_unit, rate_unit)


def _unit_factor(option: str, unit: str | None, units: dict) -> float:
    if unit is None:
        return 1.0
    if unit not in units:
        raise ConfigError(f"{option}: unknown unit {unit!r}; known: {', '.join(units)}")
    return units[unit]


def _from_columns(path, header, data, meta, columns=None, time_unit=None, rate_unit=None) -> Recording:
    header, labels = _apply_column_map(path, header, columns)
    seconds = _unit_factor("--time-unit", time_unit, TIME_UNITS)
    t_col = _columns(path, header, data, ("t",), True)[:, 0] * seconds
    w = _columns(path, header, data, GYRO, True) * _unit_factor("--rate-unit", rate_unit, RATE_UNITS)
    q = _columns(path, header, data, QUAT, False, "attitude quaternion")
    tau = _columns(path, header, data, TORQUE, False, "commanded torque")
    h = _columns(path, header, data, MOMENTUM, False, "internal angular momentum")
    _check_arrays(path, t_col, w, q, tau, labels, h=h, time_unit=time_unit, rate_unit=rate_unit)
    if q is not None:
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return Recording(t_col, w, q, tau, meta, path.stem, h=h)


def read_parquet_recording(path: str | Path, columns: dict | None = None, time_unit: str | None = None,
                           rate_unit: str | None = None) -> Recording:
    """Read a Parquet file with the CSV format's column names (and the same sidecar).

    columns, time_unit, rate_unit: as for read_recordings.
    """
    import pyarrow.parquet as pq

    path = Path(path)
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises several unrelated types for a bad file
        raise _fail(path, f"cannot read as Parquet: {exc}") from exc
    header = list(table.column_names)
    if table.num_rows == 0:
        raise _fail(path, "no data rows", 2)
    try:
        data = np.stack([np.asarray(table[c].to_numpy(), dtype=float) for c in header], axis=1)
    except (TypeError, ValueError) as exc:
        raise _fail(path, f"non-numeric column: {exc}") from exc
    return _from_columns(path, header, data, read_sidecar(path), columns, time_unit, rate_unit)


def _phyphox_segments(text: str | None, seg_path) -> list[tuple[int, float, float]] | None:
    """(segment, start, end) of each kept window of an export's meta/segments.csv, given its
    text (None: the export has no such file, and neither has the result); seg_path names it.
    Columns start and end (s, the export's clock) are required; segment (a number; else the
    row's place from 0) and keep (false, 0 or no leave the row out) are optional; names are
    read without regard to case or surrounding spaces.
    """
    if text is None:
        return None
    table = [row for row in _csv_rows(text) if any(cell.strip() for cell in row)]
    header = table[0] if table else []
    names = [name.strip().lower() for name in header]
    if "start" not in names or "end" not in names:
        raise _fail(seg_path, f"needs columns start and end (s); the header is {header}", 1)
    rows = [dict(zip(names, (cell.strip() for cell in row))) for row in table[1:]]
    out = []
    for i, row in enumerate(rows, start=2):
        if row.get("keep", "").lower() in ("false", "0", "no"):
            continue
        try:
            out.append((int(row["segment"]) if row.get("segment") else i - 2, float(row["start"]),
                        float(row["end"])))
        except (KeyError, TypeError, ValueError):
            raise _fail(seg_path, "segment, start and end must be numbers", i) from None
    if not out:
        why = f"{len(rows)} row(s), each with keep false" if rows else "no row under its header"
        raise _fail(seg_path, f"keeps no segment ({why}): nothing to read; keep one, or remove the "
                    "file to have the free flights found")
    return out


def free_flight_windows(t, w) -> list[tuple[int, int]] | None:
    """Rows [start, stop) of each free flight in gyro rows w (n, 3) rad/s at times t (n,) s,
    found from the gyro alone (a phone's export of tosses between which a hand holds it);
    None where no row breaks the torque-free bound (the whole record may be one flight).

    Torque-free, a rigid body's principal rates obey I_i w_i' = (I_j - I_k) w_j w_k, and every
    body's moments satisfy |I_j - I_k| <= I_i, so |w'|^2 <= sum w_j^2 w_k^2 <= |w|^4 / 3 in
    any body frame: the rates cannot change faster than |w|^2 / sqrt(3) (a free body moves no
    faster than it spins). A hand holding, throwing or catching the body breaks the bound. A row
    passes where the rates' local slope (a least-squares line through FLIGHT_SLOPE_ROWS samples)
    is within the bound plus FLIGHT_NOISE_Z times the slope's noise (the white-noise level of
    the record, sensors.estimate_white_noise). A flight is a run of passing rows, less the
    slope's half-width at each end (the rows an impulse there reaches), of at least
    FLIGHT_MIN_ROWS rows, turning the body at least FLIGHT_MIN_TURN rad, where the bound exceeds
    the noise allowance on most rows (a body at rest or turned slowly in the hand passes on noise
    alone), and across no dropout (an interval over GAP_FACTOR times the median: phyphox paused,
    say, while the hand moved the body): [] where the bound is broken or a dropout falls and no
    span qualifies; None also for fewer than FLIGHT_SLOPE_ROWS rows. Free of units: the same
    motion run k times faster (t / k, w k, its noise k) gives the same rows.
    """
    t, w = np.asarray(t, float), np.asarray(w, float)
    half = FLIGHT_SLOPE_ROWS // 2
    if t.size < FLIGHT_SLOPE_ROWS:
        return None
    times = np.lib.stride_tricks.sliding_window_view(t, FLIGHT_SLOPE_ROWS)
    times = times - times.mean(axis=1, keepdims=True)
    spread = np.sum(times ** 2, axis=1)  # (n - 2 half,) s^2
    rates = np.lib.stride_tricks.sliding_window_view(w, FLIGHT_SLOPE_ROWS, axis=0)  # (m, 3, rows)
    slope = np.linalg.norm(np.einsum("kir,kr->ki", rates, times), axis=1) / spread
    speed2 = np.sum(w[half:t.size - half] ** 2, axis=1)
    bound = speed2 / np.sqrt(3.0)
    allowance = FLIGHT_NOISE_Z * np.linalg.norm(estimate_white_noise(w)) / np.sqrt(spread)
    steps = np.diff(t)
    gap = np.r_[steps > GAP_FACTOR * np.median(steps), False]  # a dropout after the row
    across = np.lib.stride_tricks.sliding_window_view(gap, FLIGHT_SLOPE_ROWS)[:, :-1].any(axis=1)
    passed = (slope <= bound + allowance) & ~across  # no flight runs across a dropout
    if passed.all():
        return None
    edges = np.flatnonzero(np.diff(np.r_[0, passed.astype(np.int8), 0]))
    flights = []
    for a, b in zip(edges[::2] + 2 * half, edges[1::2]):  # rows of the run, less half at each end
        if b - a < FLIGHT_MIN_ROWS:
            continue
        turn = np.sum(np.sqrt(np.sum(w[a:b] ** 2, axis=1))[:-1] * np.diff(t[a:b]))
        spins = bound[a - half:b - half] > allowance[a - half:b - half]  # beyond the noise's allowance
        if turn >= FLIGHT_MIN_TURN and spins.mean() > 0.5:
            flights.append((int(a), int(b)))
    return flights


def read_phyphox(path: str | Path, columns: dict | None = None, time_unit: str | None = None,
                 rate_unit: str | None = None) -> list[Recording]:
    """A phyphox export: its folder or "Raw Data.csv", the .zip its CSV export writes (the same
    files) or the .xlsx its Excel export writes (sheet "Raw Data"; optional dependency openpyxl).
    With meta/segments.csv (not written by phyphox: a user's own), each kept free-flight window
    [start, end] becomes its own recording (meta "window", "window_source":
    "meta/segments.csv"). Without it, each free flight the gyro shows (free_flight_windows)
    does, named "NAME flight K" (meta "window_source": WINDOW_FOUND); the whole file is one
    recording where no row breaks the torque-free bound, or, said in its meta (WINDOW_NONE_FOUND),
    where no flight is found. columns (t, wx, wy, wz only) replace phyphox's own names; units as
    for read_recordings.
    """
    path = Path(path)
    if path.suffix.lower() == ".zip":
        label, source, seg_path = path.stem, path, f"{path}: meta/segments.csv"
        (header, data), segments = _zipped_export(path)
    elif path.suffix.lower() == ".xlsx":
        label, source, seg_path = path.stem, path, None
        (header, data), segments = _xlsx_table(path), None
    else:
        source = path / "Raw Data.csv" if path.is_dir() else path
        label, seg_path = source.parent.name, source.parent / "meta" / "segments.csv"
        header, data = _read_table(source)
        segments = _phyphox_segments(seg_path.read_text() if seg_path.exists() else None, seg_path)
    mapping = dict(zip(("t",) + GYRO, PHYPHOX_COLUMNS)) | dict(columns or {})
    missing = [name for target, name in mapping.items()
               if name not in header and target not in (columns or {})]
    if missing:
        raise _fail(source, f"missing phyphox column(s) {missing}", 1, missing[0])
    rec = _from_columns(source, header, data, {"source": str(source)}, mapping, time_unit, rate_unit)
    t, w = rec.t, rec.w
    if segments is None:
        flights = free_flight_windows(t, w)
        if flights is None:
            return [Recording(t, w, meta=rec.meta, name=label)]
        if not flights:  # the gyro shows torques and no free flight: the whole file, said so
            return [Recording(t, w, name=label, meta={**rec.meta, "window": [float(t[0]), float(t[-1])],
                                                       "window_source": WINDOW_NONE_FOUND})]
        return [Recording(t[a:b], w[a:b], name=f"{label} flight {k}", meta={
            "source": str(source), "flight": k, "window": [float(t[a]), float(t[b - 1])],
            "window_source": WINDOW_FOUND}) for k, (a, b) in enumerate(flights, start=1)]
    recs = []
    for seg, start, end in segments:
        mask = (t >= start) & (t <= end)
        if mask.sum() < MIN_SAMPLES:
            raise _fail(seg_path, f"segment {seg} [{start}, {end}] s holds {mask.sum()} samples",
                        column="start")
        recs.append(Recording(t[mask], w[mask], meta={"source": str(source), "segment": seg,
                                                      "window": [start, end],
                                                      "window_source": "meta/segments.csv"},
                              name=f"{label} segment {seg}"))
    return recs


def _zipped_export(path: Path) -> tuple[tuple[list[str], np.ndarray], list | None]:
    """(header, rows) of the "Raw Data.csv" in a zipped phyphox export, and the kept windows of
    its meta/segments.csv (None without one): the files at the archive's top or in one folder.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.namelist()
            names = [n for n in members if n.rsplit("/", 1)[-1] == "Raw Data.csv"]
            if len(names) != 1:
                raise _fail(path, f"a phyphox export holds one 'Raw Data.csv'; this archive holds "
                            f"{len(names)}")
            seg_name = names[0][: -len("Raw Data.csv")] + "meta/segments.csv"
            astray = [n for n in members if n.endswith("segments.csv") and n != seg_name]
            if astray:
                raise _fail(path, f"{astray[0]} is not beside {names[0]} (expected {seg_name})")
            table = _parse_table(_text(archive.read(names[0]), path, names[0]), f"{path}: {names[0]}")
            text = _text(archive.read(seg_name), path, seg_name) if seg_name in members else None
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, RuntimeError, NotImplementedError) as exc:
        raise _fail(path, f"cannot read as a zipped phyphox export: {exc}") from exc
    return table, _phyphox_segments(text, f"{path}: {seg_name}")


def _text(data: bytes, path: Path, member: str) -> str:
    """A zip member's bytes as text (UTF-8, a byte-order mark dropped)."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise _fail(path, f"{member} is not a text file") from None


#: The sheet of a phyphox Excel export that holds the gyro (its "Raw Data" set).
PHYPHOX_SHEET = "Raw Data"


def _xlsx_table(path: Path) -> tuple[list[str], np.ndarray]:
    """(header, rows) of the "Raw Data" sheet of a phyphox Excel export (openpyxl reads it):
    the columns under a header cell; an empty or non-numeric cell is refused, naming its row
    and column.
    """
    try:
        import openpyxl
    except ImportError:
        raise _fail(path, "reading a phyphox Excel export needs openpyxl: pip install "
                    "'inertia-gym[xlsx]' (or export CSV from phyphox)") from None
    try:
        book = openpyxl.load_workbook(path, read_only=True, data_only=True)
        try:
            if PHYPHOX_SHEET not in book.sheetnames:
                raise _fail(path, f"no sheet {PHYPHOX_SHEET!r} (the sheets are {book.sheetnames}): "
                            "not a phyphox gyro export")
            rows = list(book[PHYPHOX_SHEET].iter_rows(values_only=True))
        finally:
            book.close()
    except RecordingError:
        raise
    except Exception as exc:  # openpyxl raises several unrelated types for a bad file
        raise _fail(path, f"cannot read as an Excel workbook: {exc}") from exc
    named = [i for i, cell in enumerate(rows[0] if rows else ()) if cell is not None and str(cell).strip()]
    if not named:
        raise _fail(path, f"sheet {PHYPHOX_SHEET!r} is empty (a header row is required)", 1)
    header = [str(rows[0][i]).strip() for i in named]
    data = []
    for r, row in enumerate(rows[1:], start=2):
        cells = [row[i] if i < len(row) else None for i in named]
        if all(cell is None for cell in cells):
            continue
        for name, cell in zip(header, cells):
            if not isinstance(cell, (int, float)) or isinstance(cell, bool):
                raise _fail(path, "an empty cell" if cell is None else f"not a number: {cell!r}", r, name)
        data.append([float(cell) for cell in cells])
    if not data:
        raise _fail(path, "no data rows after the header", 2)
    return header, np.asarray(data, dtype=float)


#: meta["window_source"] of a free flight read_phyphox found from the gyro, and of an export
#: without meta/segments.csv where it found none.
WINDOW_FOUND = "found from the gyro (the export has no meta/segments.csv)"
WINDOW_NONE_FOUND = ("the whole export: it has no meta/segments.csv, and the gyro shows no free flight "
                     f"(the rates break the torque-free bound, and no span within it holds "
                     f"{FLIGHT_MIN_ROWS} samples turning half a turn)")


def window_note(start: float, end: float, source: str) -> str | None:
    """A sentence on the window from start to end (s) of a phyphox export without
    meta/segments.csv (source: WINDOW_FOUND or WINDOW_NONE_FOUND); None for any other source.
    """
    how = "write meta/segments.csv (segment,start,end) to choose the windows yourself"
    if source == WINDOW_NONE_FOUND:
        return f"{source}: its free flights, if any, were not found; {how}"
    if source != WINDOW_FOUND:
        return None
    return (f"free flight from t = {start:.6g} to {end:.6g} s, found from the gyro: the export has no "
            "meta/segments.csv, and there the rates stay within what a free body's own motion "
            f"allows (|dw/dt| <= |w|^2/sqrt(3)); {how}")


def read_recordings(path: str | Path, columns: dict | None = None, time_unit: str | None = None,
                    rate_unit: str | None = None) -> list[Recording]:
    """Any supported input: project CSV, Parquet, a phyphox export (its folder or "Raw Data.csv",
    or the .zip or .xlsx phyphox writes), or a folder holding recordings at any depth
    (recording_sources: phyphox export folders, project CSV and Parquet files, each then named
    by its path below that folder, e.g. "round1/Gyroscope rotation rate ... segment 0" or
    "throws/LOG00186"). Returns one or more.

    columns: {format name: the file's column name}, e.g. {"t": "time", "wx": "gx"}: format names
        as in COLUMN_NAMES; an unknown one, or a file column not in the header, is refused.
    time_unit: "s", "ms" or "us"; rate_unit: "rad/s" or "deg/s". None (default): seconds and
        rad/s, refused when evidently otherwise (check_units). Stated: converted and trusted.
    A recording whose logged torque or momentum has gaps comes as its pieces (split_at_gaps).
    """
    path = Path(path)
    if not path.is_dir() or (path / "Raw Data.csv").exists():
        return read_source(path, None, columns, time_unit, rate_unit)
    return [rec for name, source in recording_sources(path)
            for rec in read_source(source, name, columns, time_unit, rate_unit)]


#: Suffixes of the recording files a folder is searched for: the project's CSV and Parquet (a
#: phyphox .zip or .xlsx is read when given itself: in a data folder such files are as often an
#: export's copy beside it unzipped, or a spreadsheet of results).
RECORDING_SUFFIXES = (".csv", ".parquet")


def recording_sources(folder: str | Path) -> list[tuple[str, Path]]:
    """(name, path) of every recording a folder holds at any depth, sorted: each phyphox export
    (a folder holding 'Raw Data.csv'; its own meta/ files are not recordings) and each file
    outside the exports with a suffix of RECORDING_SUFFIXES (project CSV or Parquet), named by
    its path below folder (a file without its suffix, but with it where another source would
    have the same name: X.csv beside X.parquet or beside the export X/). RecordingError where
    it holds none.
    """
    folder = Path(folder)
    exports = sorted(raw.parent for raw in folder.rglob("Raw Data.csv"))
    files = sorted(f for f in folder.rglob("*") if f.is_file() and f.suffix.lower() in RECORDING_SUFFIXES
                   and not any(export in f.parents for export in exports))
    sources = [(export.relative_to(folder).as_posix(), export) for export in exports]
    exported = {name for name, _ in sources}
    for f in files:  # a file named as an export or another file (X.csv beside X/) keeps its suffix
        name = f.relative_to(folder).with_suffix("").as_posix()
        clash = name in exported or sum(g.with_suffix("") == f.with_suffix("") for g in files) > 1
        sources.append((f.relative_to(folder).as_posix() if clash else name, f))
    if not sources:
        raise RecordingError(f"{folder}: a folder must be a phyphox export holding 'Raw Data.csv', or hold "
                             "such exports or recordings (.csv, .parquet) at any depth")
    return sorted(sources)


def read_source(path: str | Path, name: str | None = None, columns: dict | None = None,
                time_unit: str | None = None, rate_unit: str | None = None) -> list[Recording]:
    """The recordings of one file or phyphox export (read_recordings' options), named name (and
    the segment or piece, if any) in place of the reader's own name where name is given.
    """
    label, recs = _read_any(Path(path), dict(columns=columns, time_unit=time_unit, rate_unit=rate_unit))
    return [piece if name is None else dataclasses.replace(piece, name=name + piece.name[len(label):])
            for rec in recs for piece in split_at_gaps(rec)]


def _read_any(path: Path, units: dict) -> tuple[str, list[Recording]]:
    """(the reader's name of the recording, its recordings) of one file or phyphox export."""
    if not path.exists():
        raise RecordingError(f"{path}: no such file or folder")
    if path.is_dir():
        return path.name, read_phyphox(path, **units)
    if path.suffix.lower() == ".parquet":
        return path.stem, [read_parquet_recording(path, **units)]
    if path.suffix.lower() in (".zip", ".xlsx"):
        return path.stem, read_phyphox(path, **units)
    with path.open(errors="replace") as fh:
        first = fh.readline()
    if "Gyroscope x" in first:
        return path.parent.name, read_phyphox(path, **units)
    return path.stem, [read_csv_recording(path, **units)]


def write_recording(path: str | Path, rec: Recording, sidecar: dict | None = None) -> None:
    """Write rec as the project's CSV (and REC.json). Refuses to overwrite an existing file.

    Optional column groups (q, tau, h) are written when present; sidecar defaults to rec.meta.
    """
    path = Path(path)
    side = path.with_suffix(".json")
    for target in (path, side):
        if target.exists():
            raise RecordingError(f"{target}: exists; refusing to overwrite (choose another --out)")
    cols = [rec.t[:, None], rec.w]
    names = ["t", *GYRO]
    if rec.q is not None:
        cols.append(rec.q)
        names += QUAT
    if rec.tau is not None:
        cols.append(rec.tau)
        names += TORQUE
    if rec.h is not None:
        cols.append(rec.h)
        names += MOMENTUM
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = ["%.17g"] + ["%.10g"] * (len(names) - 1)  # time in full: a clock of 1.7e9 s keeps its ms
    np.savetxt(path, np.hstack(cols), delimiter=",", header=",".join(names), comments="", fmt=fmt)
    side.write_text(json.dumps(sidecar if sidecar is not None else rec.meta, indent=2) + "\n")
