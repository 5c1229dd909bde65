"""gyro_scale: the gyro reads the rates times (1 + s), s per axis, constant or drifting."""

from __future__ import annotations

from typing_extensions import override

from inertia_gym.discrepancy.effects.base import _signed, register
from inertia_gym.discrepancy.effects.gyro_error import _GyroError

#: Largest gyro scale-factor error fitted, per axis (relative), and of its drift.
GYRO_SCALE_BOUND = 0.1


@register
class GyroScale(_GyroError):
    """Gyro reads (1 + s) w, s per axis, constant or drifting (_GyroError's forms: a scale factor
    that follows the sensor's temperature over a long record; without the drifting form, a
    20-min record drifting by 1-2 % reads as a drifting bias, a rotor and a constant scale, the
    inertia 2-4 % off).
    """

    name, params, size, family = "gyro_scale", ("scale",), 3, "gyro error"
    units = {"scale": "", "profile": "", "profile_t": "s"}
    # A common gyro scale s and a torque scale coincide only while the gyroscopic term w x Jw is
    # negligible beside the torque; on a spinning body they separate, and where they do not,
    # their delta BICs are close and the gap rule reports it.
    ambiguities = (("inertia", "a common gyro scale is not identifiable without torque or attitude "
                    "(only per-axis differences are)"),)
    varying_ambiguities = (("gyro_bias", (
        "a scale factor that drifts and a bias that drifts differ only through the rates they "
        "multiply: where those change little over the record, one reads as the other")),)
    # a scale-factor error within 10 %: beyond any gyro's uncalibrated error (MEMS data sheets
    # give <= 3 %); larger fitted scales would be another effect's missing physics
    BOUND = GYRO_SCALE_BOUND

    @override
    def draw(self, rng, body):
        return {"scale": _signed(rng, 0.01, 0.05, 3)}

    @override
    def _level(self, d):
        return 0.01

    @override
    def read(self, w, error):
        return w * (1.0 + error)
