"""The record and its timing helpers: Recording (gyro samples with, optionally, attitude,
commanded torque and known internal angular momentum, its sidecar and its name), the format's
column names, the gaps in a logged input (input_gaps, check_input_gaps, split_at_gaps) and the
regular clock that scattered time stamps are placed on (regular_clock, interpolation_residual,
retimed, retimed_note).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.errors import RecordingError

GYRO = ("wx", "wy", "wz")
QUAT = ("qw", "qx", "qy", "qz")
TORQUE = ("tau_x", "tau_y", "tau_z")
MOMENTUM = ("h_x", "h_y", "h_z")
COLUMN_NAMES = ("t",) + GYRO + QUAT + TORQUE + MOMENTUM
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
    body sampled at the uneven instants its stamps record reads as better fitted by an even
    clock: a clean record then placed there reads as an internal momentum (a smallsat at 10 Hz,
    stamps right within +-30 % of the interval).
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
    like physics (on Basilisk, stamps scattered by +-10 % of the interval make a clean record
    read as aero_drag, by +-2 % a record with bursts as internal_dissipation).
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
