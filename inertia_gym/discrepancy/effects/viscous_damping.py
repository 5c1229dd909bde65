"""viscous_damping: linear drag on the rotation, constant or changing over the record."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import inertia6, matrix6, register
from inertia_gym.discrepancy.effects.drag import _Drag, _drag_matrix


@register
class ViscousDamping(_Drag):
    """Torque -C w (C symmetric, N·m·s). Two forms: constant C, and varying, -s(t) C w, where
    the coefficient changes over the record by a factor s(t) >= 0, piecewise linear through
    knots at profile_t, s = 1 at the first (a thrown plate's rotational damping grows with the
    air speed across it, which the flight changes, as on a racquet's intermediate-axis flip).
    The varying vector is
    [C (6), profile_t (K, held), profile (K, the first held at 1)].
    """

    name = "viscous_damping"
    units = {"c": "N·m·s", "profile": "", "profile_t": "s"}
    ambiguities = (("aero_drag", "-C w and -|w| C w coincide while |w| stays nearly constant"),)
    # fewer knots than the time-varying momentum's: a coefficient that follows the flight, not a
    # free torque history
    ROWS_PER_KNOT, KNOTS = 12, (4, 8)
    varying_ambiguities = (("internal_momentum", (
        "a drag coefficient that changes over the record and a momentum that changes along one "
        "body axis both change the spin's decay in time; where the body has no rotor, read it "
        "as the drag")),)

    @override
    def _scale(self, d):
        return 0.01 * d.j_ref

    @override
    def draw(self, rng, body):
        return {"c": np.diag(rng.uniform(0.004, 0.015, 3) * body.j)}

    @override
    def form_size(self, form, d):
        return 6 if form != "varying" else 6 + 2 * self.knots(d)

    @override
    def unpack(self, p):
        if p.size == 6:
            return {"c": matrix6(p)}
        k = (p.size - 6) // 2
        return {"c": matrix6(p[:6]), "profile_t": np.array(p[6:6 + k]), "profile": np.array(p[6 + k:])}

    @override
    def pack(self, params):
        c = inertia6(_drag_matrix(params["c"]))
        if "profile" not in params:
            return c
        return np.concatenate([c, np.asarray(params["profile_t"], float),
                               np.asarray(params["profile"], float)])

    def _flat(self, d) -> np.ndarray:
        """The varying form's knots and a factor of 1 throughout (2K,)."""
        k = self.knots(d)
        return np.concatenate([np.linspace(d.t[0], d.t[-1], k), np.ones(k)])

    @override
    def bounds(self, form, d):
        lo, hi = super().bounds(form, d)
        if form == "varying":
            lo[6 + self.knots(d):] = 0.0  # the factor: no negative drag
        return lo, hi

    @override
    def held(self, form, d):
        out = np.zeros(self.form_size(form, d), bool)
        if form == "varying":
            out[6:6 + self.knots(d) + 1] = True  # knot times, and s = 1 at the first
        return out

    @override
    def typical(self, form, d):
        if form != "varying":
            return super().typical(form, d)
        return np.concatenate([np.full(6, self._scale(d)), np.ones(2 * self.knots(d))])

    @override
    def starts(self, form, d, probe):
        if form != "varying":
            return super().starts(form, d, probe)
        flat = self._flat(d)
        return [np.r_[np.zeros(6), flat]] + probe.best_of([np.r_[c, flat] for c in self._trials(d)], keep=2)

    @override
    def neutral(self, form, d, base):
        return np.zeros(6) if form != "varying" else np.r_[np.zeros(6), self._flat(d)]

    @override
    def nested(self, form, d, p):
        return np.r_[p[:6], self._flat(d)] if form == "varying" else None

    @override
    def feasible(self, p, inertia):
        return np.r_[super().feasible(p[:6], inertia), p[6:]]

    @override
    def face(self, p):
        rows = super().face(p[:6])
        return np.hstack([rows, np.zeros((rows.shape[0], p.size - 6))])

    @override
    def disturbance(self, params):
        return {"damping": _drag_matrix(params["c"])}

    @override
    def damping_factor(self, params, t):
        if "profile" not in params:
            return None
        return np.interp(t, params["profile_t"], params["profile"])
