"""The gyro errors' shared form (gyro_bias, gyro_scale): constant, or drifting along a spline."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, _spline_basis

#: Shortest spacing (s) of the knots of a drifting gyro bias or scale: a gyro's errors wander over
#: tens of seconds to hours (the flat of its Allan deviation, temperature), so over a shorter
#: record they are constant, and an error free to change faster would stand in for the body's own
#: motion (hence also one turn of the body at least between knots).
BIAS_KNOT_SPACING_S = 30.0


class _GyroError(EffectModel):
    """A gyro error per axis, e(t) = e + m(t), in two forms: constant e, and varying (an error
    that drifts: bias instability, temperature), m per axis the cubic spline (not-a-knot) through
    knots at profile_t, m = 0 at the first; only on records long enough for knots
    BIAS_KNOT_SPACING_S and one turn of the body (2 pi / omega_ref) apart, ROWS_PER_KNOT rows
    each, KNOTS in number. The varying vector is [e (3), profile_t (K, held), profile (K x 3 row
    by row, the first row held at 0)]. Subclasses give how the gyro reads with it (read), its
    typical size (_level) and bounds (BOUND, None for none).
    """

    ROWS_PER_KNOT, KNOTS = 25, (4, 16)
    BOUND: ClassVar[float | None] = None

    def _level(self, d) -> float:
        raise NotImplementedError

    def read(self, w: np.ndarray, error: np.ndarray) -> np.ndarray:
        """What the gyro reads (..., n, 3) of rates w (..., n, 3) with the error (n, 3) or (3,)."""
        raise NotImplementedError

    @override
    def knot_room(self, d):
        spacing = max(BIAS_KNOT_SPACING_S, 2.0 * np.pi / d.omega_ref)
        return min(super().knot_room(d), int(d.duration // spacing))

    @override
    def form_size(self, form, d):
        return 3 if form != "varying" else 3 + 4 * self.knots(d)

    @override
    def unpack(self, p):
        key = self.params[0]
        if p.size == 3:
            return {key: np.array(p)}
        k = (p.size - 3) // 4
        return {key: np.array(p[:3]), "profile_t": np.array(p[3:3 + k]),
                "profile": np.array(p[3 + k:]).reshape(k, 3)}

    @override
    def pack(self, params):
        error = np.broadcast_to(np.ravel(np.asarray(params[self.params[0]], float)), (3,)).copy()
        if "profile" not in params:
            return error
        return np.concatenate([error, np.asarray(params["profile_t"], float),
                               np.ravel(np.asarray(params["profile"], float))])

    def _flat(self, d) -> np.ndarray:
        """The varying form's knots and no drift (4K,)."""
        k = self.knots(d)
        return np.concatenate([np.linspace(d.t[0], d.t[-1], k), np.zeros(3 * k)])

    @override
    def bounds(self, form, d):
        lo, hi = super().bounds(form, d)
        if self.BOUND is not None:  # the error and its drift; not the knot times
            k = self.knots(d) if form == "varying" else 0
            for part in (slice(0, 3), slice(3 + k, None)):
                lo[part], hi[part] = -self.BOUND, self.BOUND
        return lo, hi

    @override
    def held(self, form, d):
        out = np.zeros(self.form_size(form, d), bool)
        if form == "varying":
            out[3:3 + self.knots(d) + 3] = True  # knot times, and m = 0 at the first knot
        return out

    @override
    def typical(self, form, d):
        level = self._level(d)
        if form != "varying":
            return np.full(3, level)
        k = self.knots(d)
        return np.concatenate([np.full(3, level), np.ones(k), np.full(3 * k, level)])

    @override
    def starts(self, form, d, probe):
        return [np.zeros(3)] if form != "varying" else [np.r_[np.zeros(3), self._flat(d)]]

    @override
    def neutral(self, form, d, base):
        return np.zeros(3) if form != "varying" else np.r_[np.zeros(3), self._flat(d)]

    @override
    def nested(self, form, d, p):
        return np.r_[p[:3], self._flat(d)] if form == "varying" else None

    @override
    def gyro(self, params, w, t):
        error = np.asarray(params[self.params[0]], float)
        if "profile" in params:
            basis = _spline_basis(np.asarray(params["profile_t"], float).tobytes(),
                                  np.ascontiguousarray(t, float).tobytes())
            error = error + basis @ np.asarray(params["profile"], float)
        return self.read(w, error)
