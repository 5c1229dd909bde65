"""Whether a fitted effect is physics the body or its sensor plausibly has.

Two judges: the effect's own plausible range (EffectModel.implausible: a gyro bias beyond what
a gyro's zero-rate offset reaches), and, where attitude is recorded, the attitude itself, which
rules out a gyro term whose removal from the rates moves the attitude integrated from them away
from the recorded one. The selection (fit.search) admits no implausible effect; the report says
what such an effect would have fitted.
"""

from __future__ import annotations

import numpy as np
from scipy import interpolate
from scipy.spatial.transform import Rotation

from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.model import integrated_attitude


def attitude_rules_out(name: str, params: dict, d, evidence: float) -> str | None:
    """Why d's recorded attitude rules out the fitted gyro error `name` (params), or None.

    A term that changes what the gyro reads (EffectModel.gyro) is taken out of the rates (to
    first order: w - (gyro(w) - w)); a real gyro error makes the attitude integrated from the
    rates as read drift from the recorded one, so the attitude integrated from the corrected
    rates over each segment, from its recorded start, comes closer to the recorded attitude. It
    is ruled out where it moves away by a Gaussian likelihood ratio over `evidence` (the
    selection's bar for an effect): 3 n ln(rss_corrected / rss_as_read), n the
    attitude samples after each segment's first. None without attitude, or for a term that does
    not change the reading.
    """
    model = REGISTRY[name]
    if d.q is None:
        return None
    read = np.asarray(model.gyro(params, d.w, d.t), float)
    if np.array_equal(read, d.w):
        return None
    corrected = d.w - (read - d.w)
    measured = Rotation.from_quat(np.asarray(d.q, float)[:, [1, 2, 3, 0]])  # scalar first in the file
    rss, n = np.zeros(2), 0
    for a, b in zip(d.seg[:-1], d.seg[1:]):
        if b - a < 2:
            continue
        relative = measured[a].inv() * measured[a:b]  # the body at each sample in its axes at a
        for i, rates in enumerate((d.w[a:b], corrected[a:b])):
            turned = Rotation.from_matrix(_attitude_between_samples(d.t[a:b], rates))
            rss[i] += float(np.sum((relative.inv() * turned).as_rotvec()[1:] ** 2))
        n += b - a - 1
    if n == 0 or not rss[0] > 0:
        return None
    ratio = 3 * n * np.log(rss[1] / rss[0])
    if ratio <= evidence:
        return None
    return (f"the recorded attitude rules it out: with it taken out of the rates, the attitude "
            f"integrated from them moves away from the recorded one (likelihood ratio {ratio:.3g}, "
            f"over {evidence:g})")


#: rad: the largest turn of one integration step of :func:`_attitude_between_samples`; its
#: midpoint rule then errs by far less than any attitude sensor's noise.
ATTITUDE_STEP_RAD = 0.01


def _attitude_between_samples(t, rates) -> np.ndarray:
    """(n, 3, 3) the body's axes at each sample time t (n,) s in its axes at t[0], integrated
    from the rates (n, 3) rad/s through a cubic spline of them, in steps that turn the body by at
    most ATTITUDE_STEP_RAD: the rates between samples curve, and a step of a whole sample
    interval at the rates' mean would put its own drift in the attitude.
    """
    turn = np.max(np.linalg.norm(rates, axis=1)) * np.max(np.diff(t))
    sub = max(1, int(np.ceil(turn / ATTITUDE_STEP_RAD)))
    fine = np.r_[(t[:-1, None] + np.diff(t)[:, None] * (np.arange(sub) / sub)).ravel(), t[-1]]
    spline = interpolate.CubicSpline(t, rates, axis=0) if t.size > 3 else None
    at = spline(fine) if spline is not None else np.stack(
        [np.interp(fine, t, rates[:, i]) for i in range(3)], 1)
    return integrated_attitude(fine, at)[::sub]


def implausible(name: str, params: dict, d, evidence: float) -> str | None:
    """Why effect `name`'s fitted params are not physics the body or sensor of d plausibly has:
    beyond its plausible range (EffectModel.implausible, given the sidecar d.meta), or ruled out
    by the recorded attitude (:func:`attitude_rules_out` at the likelihood ratio `evidence`);
    None where neither.
    """
    return REGISTRY[name].implausible(params, d.meta, d) or attitude_rules_out(name, params, d, evidence)
