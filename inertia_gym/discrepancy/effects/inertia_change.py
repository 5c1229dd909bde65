"""inertia_change: the inertia changes once during the recording, momentum kept."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, _signed, inertia6, matrix6, register
from inertia_gym.estimation.inertia_param import nearest_realizable

#: Least principal moment, as a share of the mean, of an inertia_change's after-inertia that
#: feasible() had to project (a body's, with no moment near zero: its rates stay finite).
AFTER_MOMENT_FLOOR = 0.01


@register
class InertiaChange(EffectModel):
    """At t_change (s) the inertia becomes J + delta_J (momentum kept); fitted at fixed trace
    where the scale is not seen.
    """

    name, params, size, family = "inertia_change", ("t_change", "delta_inertia"), 7, "mass change"
    units = {"t_change": "s", "delta_inertia": "kg·m²"}

    @override
    def draw(self, rng, body):
        eig, vec = np.linalg.eigh(body.inertia)
        new = eig * (1 + _signed(rng, 0.05, 0.15, 3))
        new *= eig.sum() / new.sum()  # a redistribution (deployment, fuel moving) at fixed trace
        return {"t_change": rng.uniform(0.3, 0.7) * body.duration,
                "delta_inertia": (vec @ np.diag(new) @ vec.T - np.asarray(body.inertia)).tolist()}

    @override
    def unpack(self, p):
        return {"t_change": p[0], "delta_inertia": matrix6(p[1:7])}

    @override
    def pack(self, params):
        return np.r_[float(params["t_change"]), inertia6(params["delta_inertia"])]

    @override
    def skip_reason(self, d):
        return "recording too short to split" if d.n_rows < 24 else None

    @override
    def bounds(self, form, d):
        lo, hi = super().bounds(form, d)
        lo[0], hi[0] = d.t[0], d.t[-1]
        return lo, hi

    @override
    def typical(self, form, d):
        return np.r_[d.duration, np.full(6, 0.01 * d.j_ref)]

    @override
    def starts(self, form, d, probe):
        return probe.change_starts()

    @override
    def penalty(self, p, d):
        # where the scale is not seen, a redistribution at fixed trace
        return [(p[1] + p[4] + p[6]) / d.trace0] if d.scale_fixed else []

    @override
    def feasible(self, p, inertia):
        # the inertia after the change is a body's too, never indefinite: where J + delta_J is
        # not, it is projected onto the nearest a body can have (nearest_realizable; unprojected,
        # fits can leave delta_J of 2 kg·m² on a body of trace 1), moved toward the isotropic inertia of
        # its trace where that left its least moment below AFTER_MOMENT_FLOOR of the mean (a
        # rod's zero moment: a convex mix of two bodies' inertias is a body's), and delta_J
        # follows
        after = np.asarray(inertia, float) + matrix6(p[1:7])
        moments = np.linalg.eigvalsh(after)
        if not np.all(np.isfinite(moments)) or (moments[0] > 0 and moments[2] <= moments[0] + moments[1]):
            return p
        near = nearest_realizable(after)
        least, mean = np.linalg.eigvalsh(near)[0], np.trace(near) / 3
        if not mean > 0:  # J + delta_J negative definite: no body is near it, no change is
            return np.r_[p[0], np.zeros(6)]
        if least < AFTER_MOMENT_FLOOR * mean:
            share = (AFTER_MOMENT_FLOOR * mean - least) / (mean - least)
            near = (1 - share) * near + share * mean * np.eye(3)
        return np.r_[p[0], inertia6(near - inertia)]

    @override
    def inertia_change(self, params):
        return float(params["t_change"]), np.asarray(params["delta_inertia"], float)
