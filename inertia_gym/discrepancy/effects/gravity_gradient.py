"""gravity_gradient: the gravity-gradient torque of an orbit."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, _unit, register


@register
class GravityGradient(EffectModel):
    """Torque 3 n^2 r x J r, r the inertial nadir in the body frame; fitted as n * nadir (3,)."""

    name, params, size, family = "gravity_gradient", ("orbit_rate", "nadir_inertial"), 3, "external torque"
    units = {"orbit_rate": "rad/s", "nadir_inertial": ""}
    keeps_invariants = True
    needs_attitude = True

    @override
    def draw(self, rng, body):
        # Sized by its signature on the gyro, not by the actuator level: the gradient torque
        # 3 n^2 r x J r is fixed in the orbit frame, so a body tumbling at omega_ref sees it turn
        # at about 2 omega_ref and its rates move by only ~ torque / (j 2 omega_ref). The peak
        # torque is drawn so that signature is 1-3 gyro sigmas, never below 3-10 % of tau_ref,
        # which is what a slow tumble (little averaging) needs; at 10 rad/s that is a few % of
        # the body's own gyroscopic torque omega^2 (J_max - J_min): visible, not dominant.
        j = body.j
        spread = max(float(np.ptp(np.linalg.eigvalsh(body.inertia))), 1e-3 * j)
        seen = rng.uniform(1.0, 3.0) * body.gyro_sigma * j * 2.0 * body.omega_ref
        torque = max(seen, rng.uniform(0.03, 0.1) * body.tau_ref)
        return {"orbit_rate": float(np.sqrt(torque / (3.0 * spread))), "nadir_inertial": _unit(rng)}

    @override
    def unpack(self, p):
        n = np.linalg.norm(p[:3])
        return {"orbit_rate": n, "nadir_inertial": p[:3] / n if n > 0 else np.array(p[:3])}

    @override
    def pack(self, params):
        nadir = np.asarray(params["nadir_inertial"], float)
        return float(params["orbit_rate"]) * nadir / np.linalg.norm(nadir)

    @override
    def typical(self, form, d):
        return np.full(3, 0.01 * d.omega_ref)

    @override
    def starts(self, form, d, probe):
        n0 = np.sqrt(d.tau_ref / (3.0 * d.j_ref))
        return probe.best_of([n0 * c for c in np.vstack([np.eye(3), -np.eye(3)])], keep=2)

    @override
    def disturbance(self, params):
        return {"orbit_rate": float(params["orbit_rate"]),
                "nadir_inertial": np.asarray(params["nadir_inertial"], float)
                if np.linalg.norm(params["nadir_inertial"]) > 0 else (0.0, 0.0, -1.0)}
