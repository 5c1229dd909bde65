"""actuator_delay: the commanded torque arrives late."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, register


@register
class ActuatorDelay(EffectModel):
    """The commanded torque arrives delay seconds late."""

    name, params, size, family = "actuator_delay", ("delay",), 1, "actuator"
    units = {"delay": "s"}
    needs_torque = True

    @override
    def draw(self, rng, body):
        return {"delay": rng.uniform(0.2, 0.6)}

    @override
    def bounds(self, form, d):
        return np.array([0.0]), np.array([0.5 * d.duration])

    @override
    def typical(self, form, d):
        return np.array([d.dt])

    @override
    def starts(self, form, d, probe):
        grid = np.geomspace(d.dt, 0.25 * d.duration, 16)
        return probe.best_of([np.array([v]) for v in grid], keep=2)

    @override
    def applied(self, params, cumulative):
        delay = float(params["delay"])
        return lambda t: cumulative(np.asarray(t) - delay)
