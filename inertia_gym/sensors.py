"""Sensors: the simulated measurement and the filter's measurement model, in one place.

Measurement vector z = (gyro w (3) rad/s, [attitude q (4), scalar first], [gravity (3),
magnetic field (3) in the body frame]); which parts are present is set by the filter
configuration (estimation/config.py). The simulator draws readings with
:func:`simulate_measurement`; the filters predict them with :func:`measurement_model` (h(x) and
its Jacobian H) and weigh them with :func:`measurement_noise` (the diagonal of R).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from inertia_gym.dynamics import quat_mul

N_STATE = 13


@nb.njit(cache=True)
def measurement_size(cfg):
    """Length of z for this configuration: 3 (+4 attitude) (+6 vector sensors)."""
    return 3 + (4 if cfg.use_quat > 0 else 0) + (6 if cfg.use_vector_sensors > 0 else 0)


@nb.njit(cache=True)
def body_vector_and_jacobian(q, v):
    """R(q)^T v (inertial -> body) and its derivative d/dq, shape (3,) and (3, 4)."""
    q0, qv = q[0], q[1:4]
    dot = qv[0] * v[0] + qv[1] * v[1] + qv[2] * v[2]
    cr = np.array(
        (qv[1] * v[2] - qv[2] * v[1], qv[2] * v[0] - qv[0] * v[2], qv[0] * v[1] - qv[1] * v[0])
    )
    sq = q0 * q0 - (qv[0] ** 2 + qv[1] ** 2 + qv[2] ** 2)
    out = sq * v + 2.0 * dot * qv - 2.0 * q0 * cr
    jac = np.empty((3, 4))
    for i in range(3):
        jac[i, 0] = 2.0 * q0 * v[i] - 2.0 * cr[i]
    skew_v = np.array(((0.0, -v[2], v[1]), (v[2], 0.0, -v[0]), (-v[1], v[0], 0.0)))
    for i in range(3):
        for j in range(3):
            jac[i, 1 + j] = (
                -2.0 * v[i] * qv[j] + 2.0 * qv[i] * v[j] + 2.0 * q0 * skew_v[i, j]
                + (2.0 * dot if i == j else 0.0)
            )
    return out, jac


@nb.njit(cache=True)
def measurement_model(x, cfg):
    """Predicted measurement h(x) (m,) and its Jacobian H (m, 13)."""
    m = measurement_size(cfg)
    h = np.zeros(m)
    big_h = np.zeros((m, N_STATE))
    for i in range(3):
        h[i] = x[4 + i]
        big_h[i, 4 + i] = 1.0
    row = 3
    if cfg.use_quat > 0:
        for i in range(4):
            h[row + i] = x[i]
            big_h[row + i, i] = 1.0
        row += 4
    if cfg.use_vector_sensors > 0:
        g_b, g_jac = body_vector_and_jacobian(x[0:4], cfg.gravity)
        m_b, m_jac = body_vector_and_jacobian(x[0:4], cfg.mag_reference)
        for i in range(3):
            h[row + i] = g_b[i]
            h[row + 3 + i] = m_b[i]
            for c in range(4):
                big_h[row + i, c] = g_jac[i, c]
                big_h[row + 3 + i, c] = m_jac[i, c]
    return h, big_h


@nb.njit(cache=True)
def measurement_noise(cfg):
    """Diagonal of R, shape (m,)."""
    m = measurement_size(cfg)
    r = np.empty(m)
    r[0:3] = cfg.gyro_sigma ** 2
    row = 3
    if cfg.use_quat > 0:
        r[row:row + 4] = cfg.quat_sigma ** 2
        row += 4
    if cfg.use_vector_sensors > 0:
        r[row:row + 3] = cfg.accel_sigma ** 2
        r[row + 3:row + 6] = cfg.mag_sigma ** 2
    return r


@nb.njit(cache=True)
def align_quaternion_sign(z, x, cfg):
    """Flip the measured quaternion to the hemisphere of the estimate (q and -q are one attitude)."""
    if cfg.use_quat > 0:
        dot = z[3] * x[0] + z[4] * x[1] + z[5] * x[2] + z[6] * x[3]
        if dot < 0.0:
            for i in range(3, 7):
                z[i] = -z[i]


@nb.njit(cache=True)
def simulate_measurement(y_true, noise, cfg, z):
    """Write the noisy measurement of the true state y_true = (q, w) (7,) into z: gyro,
    [normalised quaternion], [body vectors]; noise (13,) the draws of :func:`noise_sigmas`.
    """
    for i in range(3):
        z[i] = y_true[4 + i] + noise[i]
    row = 3
    if cfg.use_quat > 0:
        norm = 0.0
        for i in range(4):
            z[row + i] = y_true[i] + noise[3 + i]
            norm += z[row + i] ** 2
        norm = math.sqrt(norm)
        for i in range(4):
            z[row + i] /= norm
        row += 4
    if cfg.use_vector_sensors > 0:
        g_b, _ = body_vector_and_jacobian(y_true[0:4], cfg.gravity)
        m_b, _ = body_vector_and_jacobian(y_true[0:4], cfg.mag_reference)
        for i in range(3):
            z[row + i] = g_b[i] + noise[7 + i]
            z[row + 3 + i] = m_b[i] + noise[10 + i]


def noise_sigmas(cfg) -> np.ndarray:
    """(13,) standard deviations of the noise draws of :func:`simulate_measurement`: gyro (3),
    quaternion components (4), gravity (3), magnetometer (3).
    """
    return np.concatenate([np.full(3, cfg.gyro_sigma), np.full(4, cfg.quat_sigma),
                           np.full(3, cfg.accel_sigma), np.full(3, cfg.mag_sigma)])


#: Orders of the differences the white-noise level is read from: the third, and higher ones
#: where the motion is fast for the sampling (see estimate_white_noise).
NOISE_ORDERS = (3, 4, 5, 6)
#: An order's level counts as the noise's when within this factor of the lowest order's level
#: over NOISE_ORDERS: on white noise alone the third differences' level is within it (their
#: levels scatter 15 % about the truth over 100 rows, and together).
NOISE_PLATEAU = 1.25


def attitude_error(q_model, z_q) -> np.ndarray:
    """(M, 3) rad: 2 vec(q_model^* (x) z_q), sign-aligned: the measured attitude's rotation
    from the modelled one, in the body frame, for q_model and z_q (M, 4) scalar first.
    """
    conj = np.asarray(q_model, float) * np.array([1.0, -1.0, -1.0, -1.0])
    dq = quat_mul(conj, z_q)
    dq *= np.where(dq[:, :1] < 0, -1.0, 1.0)
    return 2.0 * dq[:, 1:]


def estimate_white_noise(w) -> np.ndarray:
    """(3,) rad/s: robust white-noise level of gyro rows w (n, 3), per axis from the k-th
    differences (MAD / 0.6745 / sqrt(binom(2k, k)): smooth motion cancels, the median absolute
    deviation ignores outliers) of the lowest order k in NOISE_ORDERS whose level is within
    NOISE_PLATEAU of the lowest level over the orders. Where the motion is slow for the sampling
    that is k = 3; where it is not, its own k-th differences, of size (rate x interval)^k, inflate
    the low orders' level: a phone's third differences on a racquet flipping at 30 rad/s at
    100 Hz read 31-44 mrad/s where the sixth read 2-3.5.

    Never under the rounding error of the samples' quantisation, q / sqrt(12) (q from
    quantisation_step): on a lattice coarse for the noise most differences are exactly zero and
    their median reads nothing (0 on one axis of a gyro quantised in steps of 10 sigma).
    """
    w = np.asarray(w, float)
    orders = [k for k in NOISE_ORDERS if w.shape[0] > k + 2] or [min(NOISE_ORDERS)]
    levels = []
    for k in orders:
        dk = np.diff(w, n=k, axis=0)
        mad = np.median(np.abs(dk - np.median(dk, axis=0)), axis=0) / 0.6745
        levels.append(mad / math.sqrt(math.comb(2 * k, k)))
    levels = np.array(levels)  # (orders, 3)
    on_plateau = levels <= NOISE_PLATEAU * levels.min(axis=0)
    level = levels[np.argmax(on_plateau, axis=0), np.arange(levels.shape[1])]
    return np.maximum(level, quantisation_step(w) / math.sqrt(12.0))


#: A gap between an axis's distinct values counts as a whole number of quantisation steps when
#: within this share of a step of one; gaps of more steps than QUANTUM_MAX_STEPS are not checked
#: (the values a log was written with round them by more). QUANTUM_MIN_VALUES distinct values
#: at least: on 3-5 values of a continuous reading the gaps fall near whole multiples of the
#: least by chance (0.4-15 % of axes, by Monte Carlo).
QUANTUM_TOLERANCE = 0.05
QUANTUM_MAX_STEPS = 100
QUANTUM_MIN_VALUES = 8
#: Samples off the lattice that an axis may hold and still be read as quantised: this share of
#: its samples, and one at least (a glitch, a sample a logger interpolated or wrote in full).
QUANTUM_OFF_SHARE = 0.01
#: The step is read from the least gap that recurs, as often as this share of the commonest gap
#: size at least: the pieces a value off the lattice splits a gap into recur by chance, rarely.
QUANTUM_SUPPORT = 0.25
#: Where the step so read fails, a step of it divided by 2 .. QUANTUM_DIVISORS is tried.
QUANTUM_DIVISORS = 4
#: An axis on fewer than QUANTUM_MIN_VALUES values has a step where each is read this many times
#: on average (_few_levels_step).
QUANTUM_REPEATS = 4


def quantisation_step(w) -> np.ndarray:
    """(3,) rad/s: per axis, the step q of the lattice the gyro samples w (n, 3) lie on (an
    offset plus whole multiples of q: an ADC's least significant bit, or the digits a log was
    written with), 0 where they lie on none. From the gaps between the axis's (at least
    QUANTUM_MIN_VALUES) distinct values: the least gap that recurs (as often as QUANTUM_SUPPORT
    of the commonest gap size, counting the gaps within QUANTUM_TOLERANCE of it) and those gaps
    give q (their mean), or where that fails a step of it divided by up to QUANTUM_DIVISORS
    that recurs too (a rate sweeping fast over the levels steps one level rarely: a 400-Hz
    gyro in steps of 2 sigma reads 12 gaps of one step and 44 of two); every gap of up to
    QUANTUM_MAX_STEPS steps must be a whole number of steps within QUANTUM_TOLERANCE, and those
    gaps must be at least half of all (values written to full precision have gaps of no common
    step); and the values must repeat or skip steps (gaps of more than one size): a smooth
    noise-free reading sampled evenly (a ramp) has equal gaps and no repeats, and no rounding.
    A few samples read off the lattice (a glitch, a sample a logger interpolated: at most
    QUANTUM_OFF_SHARE of the axis's samples, one at least) are passed over (_off_lattice); an
    axis with more gets 0: its level is then the stated one (no rounding added).
    """
    w = np.asarray(w, float)
    out = np.zeros(w.shape[1])
    for i in range(w.shape[1]):
        finite = w[np.isfinite(w[:, i]), i]
        values, counts = np.unique(finite, return_counts=True)
        if values.size < QUANTUM_MIN_VALUES:
            out[i] = _few_levels_step(values, finite.size)
            continue
        gaps = np.diff(values)
        ordered = np.sort(gaps)  # each gap's support: the gaps within QUANTUM_TOLERANCE of it
        support = (np.searchsorted(ordered, ordered * (1.0 + QUANTUM_TOLERANCE), side="right")
                   - np.searchsorted(ordered, ordered * (1.0 - QUANTUM_TOLERANCE)))
        common = np.flatnonzero(support >= max(2.0, QUANTUM_SUPPORT * support.max()))
        if common.size == 0:
            continue
        least = ordered[common[0]]
        allowed = max(1.0, QUANTUM_OFF_SHARE * finite.size)
        for divisor in range(1, QUANTUM_DIVISORS + 1):
            near_step = np.abs(gaps - least / divisor) <= QUANTUM_TOLERANCE * least / divisor
            if np.count_nonzero(near_step) < 2:
                continue
            q = float(np.mean(gaps[near_step]))
            on = _on_lattice(finite.size, values, counts, q)
            if on is None:
                continue
            # a finer step must hold more samples between the coarser one's levels than the
            # values off a lattice allowed there (a glitch halfway between two levels is one)
            level = np.round((values[on] - values[on][0]) / q).astype(np.int64) % divisor
            between = counts[on][level != np.bincount(level, counts[on]).argmax()].sum()
            if divisor == 1 or between > allowed:
                out[i] = q
                break
    return out


def _few_levels_step(values, samples: int) -> float:
    """The step (rad/s) of an axis read on fewer than QUANTUM_MIN_VALUES distinct values (m,),
    sorted, over `samples` samples, or 0: their least gap where each value is read
    QUANTUM_REPEATS times on average at least (a reading to full precision repeats none) and
    every gap is a whole number of it. A slow axis read by a coarse gyro sits on 2-7 levels (a
    cubesat at 0.05 rad/s, steps of 0.01: 3-9 values per axis); its rounding error, unread,
    leaves the noise level low, and physics is named to explain it (4 of 8 records).
    """
    if values.size < 2 or samples < QUANTUM_REPEATS * values.size:
        return 0.0
    gaps = np.diff(values)
    steps = gaps / gaps.min()
    return float(gaps.min()) if np.all(np.abs(steps - np.round(steps)) < QUANTUM_TOLERANCE) else 0.0


def _on_lattice(samples: int, values, counts, q: float) -> np.ndarray | None:
    """(m,) bool: which of an axis's distinct values (m,), read counts (m,) times (of `samples`),
    lie on a lattice of step q, or None where the values do not lie on one (quantisation_step's
    tests).
    """
    gaps = np.diff(values)
    steps = gaps / q
    near = steps <= QUANTUM_MAX_STEPS
    allowed = max(1.0, QUANTUM_OFF_SHARE * samples)
    # a gap between two values on the lattice is whole, so each value off it makes at most two
    # that are not: more than twice the allowed share is no lattice (and is not walked: full-
    # precision samples have a gap not whole between nearly every pair of values)
    broken = np.count_nonzero(near & (np.abs(steps - np.round(steps)) >= QUANTUM_TOLERANCE))
    if near.mean() < 0.5 or broken > 2 * allowed:
        return None
    off = min(_off_lattice(steps), _off_lattice(steps[::-1], reverse=True), key=len) if broken else []
    on = np.ones(values.size, bool)
    on[list(off)] = False
    kept = np.diff(values[on]) / q  # the gaps between the values on the lattice
    whole = np.round(kept[kept <= QUANTUM_MAX_STEPS])
    lattice = counts[~on].sum() <= allowed and whole.size > 0 and (
        on.sum() < samples - counts[~on].sum() or np.ptp(whole) > 0)
    return on if lattice else None


def _off_lattice(steps, reverse: bool = False) -> list[int]:
    """Indices of the distinct values (sorted, len(steps) + 1 of them) read off the lattice,
    from their gaps in steps (steps, (m,)): walking from the first value (from the last where
    reverse, steps then given last gap first), a gap that is not a whole number of steps
    (within QUANTUM_TOLERANCE) marks the value it reaches as off, and the gaps are summed until
    the sum is whole again (the value reached then is on the lattice). Gaps summing to over
    QUANTUM_MAX_STEPS are not checked: the walk starts afresh.
    """
    off, pending, total = [], [], 0.0
    for j, s in enumerate(steps):
        total += s
        reached = steps.size - 1 - j if reverse else j + 1
        # whole again, or too far to check (what it reached then counts as on): what led there is off
        if total > QUANTUM_MAX_STEPS or abs(total - round(total)) < QUANTUM_TOLERANCE:
            off += pending
            pending, total = [], 0.0
        else:
            pending.append(reached)
    return off + pending


def read_on_lattice(w, step, shift=0.0) -> np.ndarray:
    """Rates w (n, 3) rad/s read as a gyro on a lattice of step (3,) rad/s offset by shift (3,)
    reads them, to the nearest lattice point (step 0: an axis written in full, left as it is).
    """
    lattice = np.asarray(step, float) > 0
    unit = np.where(lattice, step, 1.0)
    return np.where(lattice, np.round((w + shift) / unit) * unit - shift, w)


def lattice_replays(rate, beneath, step, draws: int, first_unshifted: bool):
    """Yields `draws` replays (n, 3) of rates `rate` (n, 3) rad/s as a gyro on a lattice of step
    (3,) rad/s would read them: white noise of beneath (3,) rad/s added, read on the lattice
    (read_on_lattice) shifted by a random fraction of a step (the first unshifted where
    first_unshifted: the data's own lattice); seeded, the same replays for the same arguments.
    """
    rng = np.random.default_rng(0)
    for draw in range(draws):
        unshifted = first_unshifted and draw == 0
        shift = np.zeros(3) if unshifted else rng.uniform(-0.5, 0.5, 3) * step
        yield read_on_lattice(rate + rng.normal(size=np.shape(rate)) * beneath, step, shift)


def repeat_share(w) -> np.ndarray:
    """(3,) the share of consecutive rows of w (n, 3) whose reading on an axis equals the row
    before's (0 for fewer than two rows): high where the gyro reads on a lattice coarse beside its
    noise and the motion between rows.
    """
    w = np.asarray(w, float)
    return np.mean(np.diff(w, axis=0) == 0, axis=0) if len(w) > 1 else np.zeros(3)


def stated_gyro_level(stated, step) -> np.ndarray:
    """(3,) rad/s: a stated gyro noise level (a sidecar's gyro_sigma, a number or (3,)) with the
    rounding error of samples quantised in steps `step` (3,) rad/s added (quantisation_step; 0:
    none): sqrt(stated^2 + step^2 / 12) per axis (a data sheet's noise leaves out the
    telemetry's least significant bit, which on a coarse lattice is most of the error).
    """
    stated = np.broadcast_to(np.asarray(stated, float), (3,))
    return np.sqrt(stated ** 2 + np.asarray(step, float) ** 2 / 12.0)


def quantisation_note(stated, step) -> str | None:
    """A sentence where the quantisation in steps `step` (3,) rad/s raises a stated level
    (stated_gyro_level) by over 1 %, None otherwise.
    """
    stated = np.broadcast_to(np.asarray(stated, float), (3,))
    level = stated_gyro_level(stated, step)
    if not np.any(level > 1.01 * stated):
        return None
    steps = ", ".join(f"{v:.3g}" for v in step)
    return (f"the gyro samples are quantised in steps of ({steps}) rad/s; their rounding error "
            f"(step / sqrt(12)) is added to the sidecar's gyro_sigma: "
            f"({', '.join(f'{v:.3g}' for v in level)}) rad/s")


#: A stated gyro noise level and the level the samples' differences read disagree where one is
#: over this factor of the other on every axis (the read level scatters by 15 % over 100 rows).
NOISE_DISAGREE = 2.0


def stated_noise_note(w, stated, residual_rms) -> str | None:
    """A sentence where gyro samples w (n, 3) rad/s read a white-noise level (estimate_white_noise)
    over NOISE_DISAGREE times the stated level (3,) rad/s (a sidecar's gyro_sigma), or under
    1/NOISE_DISAGREE of it, on every axis, and the best fit's residual rms (3,) rad/s is beyond
    the same factor the same way (motion fast for the sampling raises the differences' level
    alone; a residual at the stated level says it is right); None where they agree.

    The stated level sets the intervals' width and the noise-based flags: stated 3x too small,
    the residual reads as 3x the noise, a mismatch; 3x too large, the intervals are 3x wider
    than the data need (without this sentence, neither is said). A level read under the stated
    one can be right: a coloured noise (the rotor throws' vibration at 200-260 Hz, sampled at
    4 kHz, reads 0.02-0.3 of their in-flight gyro_sigma, which their residuals exceed) or a
    low-passed gyro reads so too.
    """
    read = estimate_white_noise(w)
    stated = np.asarray(stated, float)
    ratio, fit_ratio = read / stated, np.asarray(residual_rms, float) / stated
    high = np.all(ratio > NOISE_DISAGREE) and np.all(fit_ratio > NOISE_DISAGREE)
    low = np.all(ratio < 1.0 / NOISE_DISAGREE) and np.all(fit_ratio < 1.0 / NOISE_DISAGREE)
    if not (high or low):
        return None
    said = (f"the samples' own high-frequency scatter reads a white-noise level of "
            f"({', '.join(f'{v:.3g}' for v in read)}) rad/s, {', '.join(f'{r:.2g}' for r in ratio)} times "
            f"the sidecar's gyro_sigma ({float(np.mean(stated)):.3g} rad/s), and the best fit leaves "
            f"{', '.join(f'{r:.2g}' for r in fit_ratio)} times it")
    if high:
        return (said + ": residuals read that much high against the sidecar's level (a mismatch that "
                "is only noise); check it (a noise density in rad/s/sqrt(Hz) is not a level: times "
                "the square root of the bandwidth), or leave it out to have the level read from the "
                "data; quantised samples or motion fast for the sampling also raise the level read")
    return (said + ": where the gyro's noise is white, the intervals are that much wider than the "
            "data need and the noise-based flags that much lenient; a coloured noise (vibration) or "
            "a low-passed gyro reads so too, and then the sidecar's level is the one to keep")


#: Share of consecutive rows an axis reads alike (mean runs of 5) from which the gyro reads on a
#: lattice coarse beside its noise and the motion between rows (coarse_lattice_note).
COARSE_REPEAT_SHARE = 0.8


def coarse_lattice_note(w) -> str | None:
    """For the filters, which count no rounding: a note where the gyro repeats its reading on
    COARSE_REPEAT_SHARE or more of the consecutive rows of an axis (w (n, 3) rad/s): it reads on a
    lattice coarse beside its noise and the motion between rows, whose rounding error follows
    the motion (the output error counts it: estimation/ml.lattice_replayed).
    """
    repeat = repeat_share(w)
    coarse = np.flatnonzero(repeat >= COARSE_REPEAT_SHARE)
    if not coarse.size:
        return None
    axes = ", ".join(f"{'xyz'[i]} {100 * repeat[i]:.0f} %" for i in coarse)
    return (f"the gyro repeats its reading from row to row ({axes} of the rows): it reads on a lattice "
            "coarse beside its noise and the motion between rows, and its rounding error follows the "
            "motion, which the filter's intervals do not count: they may be several times too narrow")
