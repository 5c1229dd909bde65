"""actuator_scale: the body receives a scaled commanded torque."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, _signed, register


@register
class ActuatorScale(EffectModel):
    """The body receives (1 + s) times the commanded torque."""

    name, params, size, family = "actuator_scale", ("scale",), 1, "actuator"
    units = {"scale": ""}
    needs_torque = True
    ambiguities = (("inertia", "the torque scale is measured against the sidecar's nominal "
                    "inertia: J/s with torque tau fits as well as J with torque s*tau, so a wrong "
                    "nominal trace reads as an actuator scale"),)

    @override
    def skip_reason(self, d):
        if d.inertia0 is None:
            return ("indistinguishable from the inertia's scale: no nominal inertia in the sidecar "
                    "to pin it")
        return super().skip_reason(d)

    @override
    def draw(self, rng, body):
        return {"scale": float(_signed(rng, 0.2, 0.5))}

    @override
    def bounds(self, form, d):
        return np.array([-0.9]), np.array([np.inf])

    @override
    def typical(self, form, d):
        return np.array([0.1])

    @override
    def applied(self, params, cumulative):
        gain = 1.0 + float(params["scale"])
        return lambda t: gain * cumulative(t)
