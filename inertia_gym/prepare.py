"""Recordings prepared for estimation: what every product does to a record before fitting it.

One layer below identify and diagnose, called once per record: which gyro samples are no
measurement (an axis clipped at the gyro's full scale), which rows at a record's ends hold an
impulse (a throw's release, a catch, a knock), and the gyro's noise level (the sidecar's, with
the rounding of a quantised gyro added, or read from the samples' high-order differences).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from inertia_gym.errors import RecordingError
from inertia_gym.recordings import (
    Recording,
    check_input_gaps,
    retimed,
    retimed_note,
    window_note,
)
from inertia_gym.sensors import (
    QUANTUM_MIN_VALUES,
    estimate_white_noise,
    quantisation_note,
    quantisation_step,
    stated_gyro_level,
)

#: A gyro axis reads as clipped where a run of its extreme value is entered and left steeply:
#: the stretch within CLIP_DROP steps (the level spacing or the noise) of it is at most 2
#: CLIP_REACH longer than its samples at the extreme (saturated_samples).
CLIP_DROP, CLIP_REACH = 3.0, 0.25
#: An impulse at a record's end: the whitened residual jumps by more than this many times its
#: median step, within this share of the record from its end.
IMPULSE_JUMP, IMPULSE_SPAN = 8.0, 0.15
#: Fewest samples a record must hold (and keep unclipped) to be fitted: the rigid model's
#: unknowns are 9 to 15 numbers, each sample gives 3.
MIN_SAMPLES = 20
#: Least total rotation angle (rad) over a record: rigid-body dynamics need the body to turn.
MIN_ROTATION = 0.1


def saturated_samples(rec: Recording) -> np.ndarray:
    """(n, 3) bool: samples the gyro clipped: each axis's extreme value on either side where it
    reads as a clip (_clipped_extreme), an axis read at one value throughout where another axis
    is read to full precision (a gyro resolving its noise there would here too), and, with a
    full scale in the sidecar (gyro_full_scale_rad_s), every sample within 1.5 steps of its
    lattice of it (an int16 gyro's positive rail is one step short of its full scale, and a
    narrower band would take a peak just under the rail for a clip).
    """
    w = rec.w
    noise, quantum = estimate_white_noise(w), quantisation_step(w)
    full = rec.meta.get("gyro_full_scale_rad_s")
    rail = (np.zeros(w.shape, dtype=bool) if full is None
            else np.abs(w) >= float(full) * (1 - 1e-9) - 1.5 * quantum)
    constant = np.ptp(w, axis=0) == 0
    fine = [not constant[i] and _full_precision(w[:, i], quantum[i]) for i in range(3)]
    out = np.zeros_like(w, dtype=bool)
    for i in range(3):
        if constant[i]:
            out[:, i] = w[0, i] != 0 and any(np.delete(fine, i))
            continue
        for a in (w[:, i], -w[:, i]):
            out[:, i] |= _clipped_extreme(a, noise[i], fine[i])
    return out | rail


def _full_precision(a: np.ndarray, quantum: float) -> bool:
    """Whether one axis's samples a (n,) rad/s are read to full precision: on no lattice
    (quantum, rad/s, 0: none; sensors.quantisation_step), no two consecutive samples alike but
    at its extremes (where a clip holds them), and values enough to tell (QUANTUM_MIN_VALUES:
    an axis read on two levels has no others).
    """
    alike = a[1:] == a[:-1]
    extreme = (a[1:] == a.max()) | (a[1:] == a.min())
    return (quantum == 0 and not np.any(alike & ~extreme)
            and np.unique(a).size >= QUANTUM_MIN_VALUES)


def _extreme_level(a: np.ndarray, noise: float) -> tuple[float, np.ndarray, float]:
    """(top, at, step) of one axis's samples a (n,) rad/s: its largest value, the samples (n,)
    bool read at it, and the step beneath it (the gap to the next value, or the noise if larger;
    inf where every sample is at the top).
    """
    top = float(a.max())
    at = a >= top * (1 - 1e-12)
    step = max(top - a[~at].max(), noise) if not at.all() else np.inf
    return top, at, step


def _clipped_extreme(a: np.ndarray, noise: float, full_precision: bool) -> np.ndarray:
    """(n,) bool: the samples of a (n,) rad/s at its largest value where that value is a clip.

    A clip reads the rate flat at its extreme, three or more consecutive samples alike. Read to
    full precision (_full_precision) nothing else does that. On a lattice, a smooth peak
    rounded to one level may also; the two differ in how the run is entered and left. A peak
    of curvature c is read at its top level over a run of L samples where c (L / 2)^2 is within
    about one step of the peak (the spacing of the levels, or the noise if larger), so the rate
    is CLIP_DROP steps below the top only (sqrt(CLIP_DROP + 1) - 1) L / 2 = L / 2 or more
    samples from the run's ends. A clip cuts the rate where it still climbs: it is that far
    below within a few samples, whatever L. So a stretch of rates within CLIP_DROP steps of the
    top, holding such a run, is a clip where at most 2 CLIP_REACH of its samples per sample at
    the top are not at the top (noise breaks a clip's run near its ends). A stretch at the
    record's start or end shows one side and is not taken alone.
    """
    top, at, step = _extreme_level(a, noise)
    bounds = np.flatnonzero(np.diff(np.r_[0, at.astype(np.int8), 0]))
    starts, stops = bounds[::2], bounds[1::2]
    long_runs = stops - starts >= 3
    if top <= 0 or not long_runs.any():
        return np.zeros(a.size, dtype=bool)
    if full_precision:
        return at
    near = np.r_[False, a > top - CLIP_DROP * step, False]  # bounded by rates well below
    edges = np.flatnonzero(np.diff(near.astype(np.int8)))
    for first, end in zip(edges[::2], edges[1::2]):
        level = np.count_nonzero(at[first:end])
        interior = first > 0 and end < a.size
        if (interior and np.any((starts[long_runs] >= first) & (starts[long_runs] < end))
                and end - first - level <= 2 * CLIP_REACH * level):
            return at
    return np.zeros(a.size, dtype=bool)


#: What a user whose gyro may have clipped at a record's ends is asked (after clips_at_the_ends)
CLIP_ADVICE = ("if the gyro clipped there, give its full scale in the sidecar (gyro_full_scale_rad_s) "
               "and those rows are left out")


def clips_at_the_ends(rec: Recording) -> list[str]:
    """Phrases, one per axis and end, where an axis holds its extreme value for its first or last
    three or more samples and then falls steeply (CLIP_DROP steps within CLIP_REACH of the run's
    length, as _clipped_extreme asks of both sides): a clip there cannot be told from a rate
    that starts or ends at its peak, so it is not left out, only said (where such a clip makes
    the fit fail, the user then knows why). Empty where the sidecar gives the full scale or
    those samples are taken as clipped already.
    """
    if rec.meta.get("gyro_full_scale_rad_s") is not None:
        return []
    w = np.asarray(rec.w, float)
    n = w.shape[0]
    noise, clipped = estimate_white_noise(w), saturated_samples(rec)
    out = []
    for i, axis in enumerate("xyz"):
        for a in (w[:, i], -w[:, i]):
            top, at, step = _extreme_level(a, noise[i])
            if top <= 0 or at.all():
                continue
            for end, held in (("first", at), ("last", at[::-1])):
                run = int(np.argmin(held))  # samples at the top from this end
                beside = (a if end == "first" else a[::-1])[run:run + max(1, int(CLIP_REACH * run))]
                rows = slice(0, run) if end == "first" else slice(n - run, n)
                if run >= 3 and not clipped[rows, i].any() and np.any(beside <= top - CLIP_DROP * step):
                    out.append(f"the {axis} axis reads {w[rows, i][0]:.4g} rad/s in its {end} {run} samples")
    return out


def end_impulses(z: np.ndarray, same: np.ndarray | None = None) -> tuple[int, int]:
    """The rows to keep, start .. stop - 1, of residual rows z (n, k) (whitened: noise ~ 1)
    without an impulse at either end (a throw's release, a catch, a knock): the residual jumps
    from row to row by more than IMPULSE_JUMP times its median jump (and by more than 1); the
    rows up to the last such jump near the start, and from the first one near the end, are left
    out (each side at most IMPULSE_SPAN of the rows). A drift the model misses grows smoothly and
    is kept. same (n - 1,) bool: whether rows i and i + 1 belong to one segment (a jump across
    segments is not an impulse); None: all do. (0, n) when nothing is left out, or z is short
    or not finite.
    """
    n = z.shape[0]
    if n < 20 or not np.all(np.isfinite(z)):
        return 0, n
    same = np.ones(n - 1, bool) if same is None else same
    jump = np.where(same, np.linalg.norm(np.diff(z, axis=0), axis=1), 0.0)
    thr = IMPULSE_JUMP * max(float(np.median(jump[same])), 1.0)
    span = int(IMPULSE_SPAN * n)
    big = np.flatnonzero(jump > thr)
    head, tail = big[big < span], big[big >= n - 1 - span]
    return (int(head.max()) + 1 if head.size else 0), (int(tail.min()) + 1 if tail.size else n)




def rate_impulses(w: np.ndarray, sigma: np.ndarray) -> tuple[int, int]:
    """Rows start .. stop - 1 of gyro rates w (n, 3) rad/s to keep without an impulse at either
    end, located on their second difference whitened by the noise sigma (3,) rad/s (white noise
    gives it sigma sqrt(6); its row i is centred on sample i + 1): no model needed.
    """
    n = w.shape[0]
    rows = end_impulses(np.diff(w, 2, axis=0) / (math.sqrt(6.0) * sigma))
    return (rows[0] + 1 if rows[0] else 0), (rows[1] + 1 if rows[1] < n - 2 else n)


def clip_hint(rec: Recording) -> str:
    """'' or a clause naming the axes held at their extreme at a record's end (clips_at_the_ends),
    to end a sentence about a misfit.
    """
    ends = clips_at_the_ends(rec)
    return "; " + "; ".join(ends) + ": " + CLIP_ADVICE if ends else ""


@dataclasses.dataclass(frozen=True)
class Prepared:
    """A recording made ready for fitting.

    rec: the recording on its regular clock (recordings.retimed), without the rows of an
    impulse at either end; saturated (n, 3) bool: its samples the gyro clipped
    (saturated_samples, found once on the whole retimed recording); usable (n,) bool: its rows
    that are measurements (no axis clipped);
    sigma (3,) rad/s: the stated gyro noise (the sidecar's gyro_sigma with the rounding of a
    quantised gyro added), None where the sidecar states none; level (3,) rad/s: the level the
    residuals are judged against (the stated one, else read from the samples' high-order
    differences: never a fit's own residual); step (3,) rad/s: the gyro's quantisation step (0:
    none); kept (start, stop): the original rows kept; notes: what was done, in words; total: the
    rows of the retimed recording, before any was left out.
    """

    rec: Recording
    saturated: np.ndarray
    sigma: np.ndarray | None
    level: np.ndarray
    step: np.ndarray
    kept: tuple[int, int]
    notes: tuple[str, ...]
    total: int

    def rows(self, start: int, stop: int) -> "Prepared":
        """The prepared record's rows start:stop, with the same noise level."""
        return dataclasses.replace(self, rec=self.rec.rows(start, stop), saturated=self.saturated[start:stop],
                                   kept=(self.kept[0] + start, self.kept[0] + stop))

    @property
    def usable(self) -> np.ndarray:
        """(n,) bool: the rows that are measurements, no axis clipped."""
        return ~self.saturated.any(axis=1)

    @property
    def sigma_source(self) -> str:
        """Where the noise level that weights the fit comes from."""
        return "sidecar gyro_sigma" if self.sigma is not None else "estimated from the residuals"


def check_recording(rec: Recording) -> np.ndarray:
    """Refuse (RecordingError) a recording no inertia can be fitted to: unsplit gaps in its
    inputs, fewer than MIN_SAMPLES (unclipped) samples, a body that does not turn, a momentum
    that is not finite. Returns the samples the gyro clipped (saturated_samples, (n, 3) bool),
    which the check reads.
    """
    check_input_gaps(rec)
    if rec.t.size < MIN_SAMPLES:
        raise RecordingError(f"{rec.name}: only {rec.t.size} samples; a fit needs at least {MIN_SAMPLES}")
    saturated = saturated_samples(rec)
    unclipped = int(np.count_nonzero(~saturated.any(axis=1)))
    if unclipped < MIN_SAMPLES:
        raise RecordingError(f"{rec.name}: the gyro clipped at its full scale in {rec.t.size - unclipped} "
                             f"of {rec.t.size} rows; a fit needs at least {MIN_SAMPLES} unclipped rows "
                             "(a gyro range above the body's rates, or a slower spin)")
    noise = float(np.median(estimate_white_noise(rec.w))) if rec.t.size > 10 else 0.0
    # the gyro's stated noise counts too: rates the data read as smooth may lie far below it
    noise = max(noise, float(rec.meta.get("gyro_sigma") or 0.0))
    rate = np.linalg.norm(rec.w, axis=1)
    peak = float(np.max(rate))
    turned = float(np.sum(0.5 * (rate[1:] + rate[:-1]) * np.diff(rec.t)))
    if peak < 5.0 * noise or turned < MIN_ROTATION:
        raise RecordingError(f"{rec.name}: the body does not rotate (peak |w| {peak:.3g} rad/s, "
                             f"gyro noise {noise:.3g} rad/s, {turned:.3g} rad turned in all): no "
                             "inertia can be identified")
    if rec.h is not None and not np.all(np.isfinite(rec.h)):
        raise RecordingError(f"{rec.name}: column h_*: NaN or infinite internal momentum")
    return saturated


def prepared(rec: Recording) -> Prepared:
    """The recording prepared once for every product (see Prepared): retimed, checked, its
    clipped rows marked, an impulse at either end located on the rates (rate_impulses) and left
    out, its noise level set.
    """
    rec = retimed(rec)
    saturated = check_recording(rec)
    clipped = saturated.any(axis=1)
    step = quantisation_step(rec.w[~clipped])
    stated = None
    if "gyro_sigma" in rec.meta:
        stated = stated_gyro_level(float(rec.meta["gyro_sigma"]), step)
        level = stated
    else:
        level = np.maximum(estimate_white_noise(rec.w[~clipped]), 1e-12)
    notes = []
    n = rec.t.size
    start, stop = rate_impulses(rec.w, level) if n >= MIN_SAMPLES else (0, n)
    if (start, stop) != (0, n) and stop - start >= MIN_SAMPLES:
        notes.append(f"{impulse_rows(rec, start, stop)} look like an impulse (a release, catch or "
                     "knock: the rates jump there far more than anywhere else): left out")
        rec = rec.rows(start, stop)
        saturated, clipped = saturated[start:stop], clipped[start:stop]
    else:
        start, stop = 0, n
    if clipped.any():
        sat = saturated
        top = ", ".join(f"{'xyz'[i]} {np.abs(rec.w[sat[:, i], i]).min():.4g}" for i in range(3)
                        if sat[:, i].any())
        notes.append(f"the gyro clipped at its full scale ({top} rad/s) in {int(clipped.sum())} of "
                     f"{clipped.size} rows: those rows are left out of the fit")
    split = rec.meta.get("split_at_gaps")
    if split:
        notes.append(f"piece {split['piece']} of {split['pieces']} (rows {split['rows'][0]}-"
                     f"{split['rows'][1]}) of a recording split at gaps of "
                     f"{', '.join(f'{g:.3g}' for g in split['gaps_s'])} s in its logged torque or "
                     "momentum; each piece is identified on its own")
    if "retimed" in rec.meta:
        notes.append(retimed_note(rec.meta["retimed"]))
    if "window_source" in rec.meta:
        window = window_note(*rec.meta["window"], rec.meta["window_source"])
        notes += [window] if window else []
    if stated is not None:
        said = quantisation_note(float(rec.meta["gyro_sigma"]), step)
        notes += [said] if said else []
    return Prepared(rec, saturated, stated, level, step, (start, stop), tuple(notes), n)


def impulse_rows(rec: Recording, start: int, stop: int) -> str:
    """The rows outside start .. stop - 1 in words, with their times: 1-based data rows of the
    file (a piece of a recording split at gaps counts from the file's first row, not its own).
    """
    n = rec.t.size
    first = (rec.meta.get("split_at_gaps") or {}).get("rows", [1])[0]
    parts = ([f"rows {first}-{first + start - 1} (to t = {rec.t[start - 1]:.6g} s)"] if start else []) + \
            ([f"rows {first + stop}-{first + n - 1} (from t = {rec.t[stop]:.6g} s)"] if stop < n else [])
    return " and ".join(parts)
