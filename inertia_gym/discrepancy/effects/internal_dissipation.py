"""internal_dissipation: energy decays inside the body, its momentum kept."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, register


@register
class InternalDissipation(EffectModel):
    """Torque -d (w - u (u . w)), u along the total momentum: energy decays, |J w + h| is kept
    (slosh, nutation dampers; d N·m·s).
    """

    name, params, size, family = "internal_dissipation", ("d",), 1, "internal motion"
    units = {"d": "N·m·s"}
    keeps_invariants = True

    @override
    def draw(self, rng, body):
        return {"d": rng.uniform(0.01, 0.04) * body.j}

    @override
    def typical(self, form, d):
        return np.array([0.01 * d.j_ref])

    @override
    def disturbance(self, params):
        return {"dissipation": float(params["d"])}
