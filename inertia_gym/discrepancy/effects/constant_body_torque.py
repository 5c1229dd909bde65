"""constant_body_torque: a constant torque fixed in the body."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, _unit, register


@register
class ConstantBodyTorque(EffectModel):
    """A constant torque fixed in the body (N·m)."""

    name, params, size, family = "constant_body_torque", ("torque",), 3, "external torque"
    units = {"torque": "N·m"}
    keeps_invariants = True

    @override
    def draw(self, rng, body):
        return {"torque": _unit(rng) * rng.uniform(0.03, 0.1) * body.tau_ref}

    @override
    def typical(self, form, d):
        return np.full(3, d.tau_ref)

    @override
    def disturbance(self, params):
        return {"constant_torque": np.asarray(params["torque"], float)}
