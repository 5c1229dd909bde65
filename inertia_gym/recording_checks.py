"""The checks of a read table, each refusing it with a RecordingError that names the file, row
and column (_fail): finite values on a physical scale, time that increases, enough samples and
a plausible gyro magnitude (_check_arrays), units evidently s and rad/s (check_units), a total
turn a model can follow (check_total_turn), and attitude quaternions that turn the body about
the axes its gyro does (check_attitude_frame).
"""

from __future__ import annotations

import numpy as np

from inertia_gym.errors import RecordingError
from inertia_gym.recording import GYRO, MIN_SAMPLES, MOMENTUM, QUAT, TORQUE
from inertia_gym.sensors import attitude_error

MAX_PLAUSIBLE_RATE = 200.0  # rad/s; larger gyro values almost surely are deg/s or mdps
#: rad the body may turn over a whole recording (about 160 000 revolutions: 0.1 rad/s for 115
#: days): the models integrate in steps of a tenth of a radian, so beyond this one trajectory
#: takes over 1e7 steps. Checked whatever the stated units.
MAX_TOTAL_TURN = 1e6
#: Largest magnitude accepted in any column: squares and products of such values stay finite.
MAX_MAGNITUDE = 1e100
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

