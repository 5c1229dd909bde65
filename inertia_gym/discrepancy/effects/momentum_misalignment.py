"""momentum_misalignment: the logged internal momentum is rotated in the body."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, _unit, register, rotvec_matrix


@register
class MomentumMisalignment(EffectModel):
    """The logged internal momentum (a rotor, wheels) is rotated by a rotation vector (rad): the
    rotor's axis in the body is not the one the log assumes.
    """

    name, params, size, family = "momentum_misalignment", ("rotvec",), 3, "logged momentum"
    units = {"rotvec": "rad"}
    needs_momentum = True
    ambiguities = (("inertia", "with one rotor (h keeping its direction) the turn about the rotor's "
                    "own axis is not seen: only where the axis points is"),)

    @override
    def draw(self, rng, body):
        return {"rotvec": _unit(rng) * np.deg2rad(rng.uniform(3.0, 10.0))}

    @override
    def typical(self, form, d):
        return np.full(3, 0.01)

    @override
    def known_momentum(self, params, h):
        return h @ rotvec_matrix(params["rotvec"]).T
