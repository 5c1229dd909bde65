"""actuator_misalignment: the commanded torque arrives rotated."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, _unit, register, rotvec_matrix


@register
class ActuatorMisalignment(EffectModel):
    """The commanded torque is rotated by a rotation vector (rad)."""

    name, params, size, family = "actuator_misalignment", ("rotvec",), 3, "actuator"
    units = {"rotvec": "rad"}
    needs_torque = True

    @override
    def draw(self, rng, body):
        return {"rotvec": _unit(rng) * np.deg2rad(rng.uniform(10.0, 25.0))}

    @override
    def typical(self, form, d):
        return np.full(3, 0.05)

    @override
    def applied(self, params, cumulative):
        rot = rotvec_matrix(params["rotvec"])
        return lambda t: cumulative(t) @ rot.T
