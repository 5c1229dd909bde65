"""gyro_bias: the gyro reads the rates plus an offset, constant or drifting."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import _signed, register
from inertia_gym.discrepancy.effects.gyro_error import _GyroError

#: A fitted gyro bias is taken for the gyro's own up to the larger of these, unless the sidecar
#: states its gyro's bound (gyro_bias_max): GYRO_BIAS_PLAUSIBLE rad/s (about 5.7 deg/s), beyond the
#: zero-rate offsets consumer MEMS gyros specify (within ±1 to ±5 deg/s), and GYRO_BIAS_OVER_NOISE
#: times the record's noise, since a noisier, lower-grade gyro has a larger offset (MEMS data
#: sheets put the offset within a few tens of times the per-sample noise at 100 Hz).
GYRO_BIAS_PLAUSIBLE = 0.1
GYRO_BIAS_OVER_NOISE = 50.0


@register
class GyroBias(_GyroError):
    """Gyro reads w + b (b rad/s per axis), constant or drifting (_GyroError's forms)."""

    name, params, size, family = "gyro_bias", ("bias",), 3, "gyro error"
    #: a screen holds the segments' rates, and a constant bias shifts exactly what those rates
    #: are read as: screened on top of another effect, it explains little of what it explains
    #: refitted with the rates, so it is refitted jointly wherever structure is left (on a slow
    #: tumble with a rotor and a bias, led by the rotor's momentum, its screen ranks below an
    #: inertia offset's: tests/discrepancy/test_fit.py)
    restarts_on_base = ("",)
    units = {"bias": "rad/s", "profile": "rad/s", "profile_t": "s"}
    varying_ambiguities = (("internal_momentum", (
        "a bias that drifts and a momentum that changes slowly both move the rates the gyro "
        "reads by a slowly changing amount; a momentum also turns the body's spin, which on a "
        "slowly turning body is small: where the body has no rotor, read it as the gyro")),
                           ("gyro_scale", (
        "a scale factor that drifts multiplies the rates by a slowly changing amount; where the "
        "rates the body turns at change little over the record, that is a bias that drifts")),)

    as_fitted = {"": "a constant offset of the rates the gyro reads",
                 "varying": "a slowly changing offset of the rates the gyro reads"}

    @override
    def implausible(self, params, meta, d):
        limit = float(meta["gyro_bias_max"]) if "gyro_bias_max" in meta else \
            max(GYRO_BIAS_PLAUSIBLE, GYRO_BIAS_OVER_NOISE * float(np.max(d.sigma)) * np.sqrt(d.block))
        # (d.sigma is the noise of a block's mean: times sqrt(block), a sample's)
        bias = np.asarray(params["bias"], float)
        if "profile" in params:  # the bias at each knot of a drifting one
            bias = bias + np.asarray(params["profile"], float)
        peak = float(np.max(np.abs(bias)))
        if peak <= limit:
            return None
        return (f"a gyro bias of {peak:.3g} rad/s is beyond the {limit:.3g} rad/s a gyro's zero-rate "
                "offset plausibly reaches" + ("" if "gyro_bias_max" in meta else
                                               " (gyro_bias_max in the sidecar states your gyro's)"))

    @override
    def draw(self, rng, body):
        return {"bias": _signed(rng, 3.0, 10.0, 3) * body.gyro_sigma}

    @override
    def _level(self, d):
        return float(np.mean(d.sigma))

    @override
    def read(self, w, error):
        return w + error
