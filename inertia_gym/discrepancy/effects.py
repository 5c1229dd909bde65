"""The physics catalogue (docs/contracts.md) as a registry of effect classes.

Units: rad/s, N·m, kg·m², s. The body obeys
    J(t) w_dot + d eta_ddot + w x (J(t) w + h + d eta_dot) = tau_applied + tau_ext,
    eta_ddot + 2 zeta Omega eta_dot + Omega^2 eta = -d . w_dot          (flexible mode)
with the gyro reading (1 + s) * w + b. Every effect sets one group of these terms, and one class
owns everything about it: its parameters and their fitted vector, a random draw sized to the
body, bounds and starts of the fit, its terms in the truth simulator (synthetic.simulate_truth:
the disturbance hook of dynamics.state_rate, an applied-torque or gyro transform, an extra torque),
its terms in the integral equation error and in the whitener (fit.py), and its known
ambiguities. Adding an effect is one subclass here with ``@register``.

Fit-side hooks receive p, the effect's slice of the fitted vector, and d, a fit.Data.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np
from scipy import signal
from typing_extensions import override

from inertia_gym.errors import ConfigError
from inertia_gym.estimation.inertia_param import inertia_from_phi, phi_from_inertia
from inertia_gym.information import inertia_from_theta

#: Modal frequencies (Hz) screened for flexible_mode: lowest, and highest as a share of Nyquist.
FLEX_BAND = (0.2, 0.8)


def skew(v) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    v = np.asarray(v, float)
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def rotvec_matrix(rotvec) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector (rad), Rodrigues' formula."""
    rv = np.asarray(rotvec, float)
    angle = np.linalg.norm(rv)
    k = skew(rv / angle) if angle > 0 else np.zeros((3, 3))
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def quat_rotations(q) -> np.ndarray:
    """(n, 4) unit quaternions -> (n, 3, 3) body-to-inertial rotation matrices."""
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def flex_filters(omega_n: float, zeta: float, dt: float):
    """Discrete (bilinear) filters of 1/(s^2 + 2 zeta Omega s + Omega^2) times 1, s, s^2."""
    den = [1.0, 2 * zeta * omega_n, omega_n ** 2]
    return [signal.bilinear(num, den, fs=1.0 / dt) for num in ([1.0], [1.0, 0.0], [1.0, 0.0, 0.0])]


def _unit(rng) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _signed(rng, lo, hi, size=None):
    return rng.uniform(lo, hi, size) * rng.choice([-1.0, 1.0], size)


def jsonable(params: dict) -> dict:
    """Parameters with numpy values turned into floats / lists."""
    return {k: (np.asarray(v).tolist() if np.ndim(v) else float(v)) for k, v in params.items()}


@dataclasses.dataclass(frozen=True)
class Body:
    """What a random draw is sized to: inertia (3, 3) kg·m², omega_ref rad/s (typical rate),
    tau_ref N·m (actuator level), gyro_sigma rad/s, duration s of the recording.
    """

    inertia: np.ndarray
    omega_ref: float
    tau_ref: float
    gyro_sigma: float
    duration: float

    @property
    def j(self) -> float:
        """Mean principal moment trace(J) / 3, kg·m²."""
        return float(np.trace(self.inertia)) / 3.0


class EffectModel:
    """Base class of a catalogue effect; every hook defaults to "this effect has no such term".

    Class attributes: ``name`` (fixed by the contract), ``params`` (named parameters), ``size``
    (length of the fitted vector p), ``needs_torque`` / ``needs_attitude`` (what the recording
    must hold), ``ambiguities`` ((other effect or "inertia", reason) pairs that the data may not
    separate), ``start_nfev`` (a cap on each start's solver run; the best start is then run to
    convergence), ``sets_inertia`` (the effect's parameters are the inertia itself: theta is
    then not fitted).
    """

    name: ClassVar[str]
    params: ClassVar[tuple[str, ...]]
    size: ClassVar[int]
    needs_torque: ClassVar[bool] = False
    needs_attitude: ClassVar[bool] = False
    ambiguities: ClassVar[tuple[tuple[str, str], ...]] = ()
    start_nfev: ClassVar[int | None] = None
    sets_inertia: ClassVar[bool] = False

    # --- parameters -------------------------------------------------------------------------
    def draw(self, rng: np.random.Generator, body: Body) -> dict:
        """Random magnitudes, sized to the body so the effect is visible but not dominant."""
        raise NotImplementedError

    def unpack(self, p: np.ndarray) -> dict:
        """Fitted vector p (size,) -> named parameters (the single parameter by default)."""
        return {self.params[0]: p[0] if self.size == 1 else p[:self.size]}

    def pack(self, params: dict) -> np.ndarray:
        """Named parameters -> the fitted vector (size,), the inverse of unpack."""
        return np.ravel(np.asarray(params[self.params[0]], float))

    # --- fit set-up -------------------------------------------------------------------------
    def skip_reason(self, d) -> str | None:
        """Why the data cannot test this effect, or None."""
        if self.needs_torque and not d.has_torque:
            return "no commanded torque in the recording"
        if self.needs_attitude and d.rot is None:
            return "needs attitude (qw..qz) columns"
        return None

    def bounds(self, d) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds (size,) of p."""
        return np.full(self.size, -np.inf), np.full(self.size, np.inf)

    def held(self, d) -> np.ndarray:
        """Bool mask (size,) of parameters held at their start by the solver (set by a scan, or
        not identifiable from d).
        """
        return np.zeros(self.size, bool)

    def inertia(self, p):
        """The model's inertia (3, 3) kg·m² when this effect sets it (else the fitted/nominal J)."""
        return None

    def starts(self, d, base, probe) -> list[np.ndarray]:
        """Starting vectors x of the joint fit (several where it is not convex): probe (a
        fit.Probe) appends an effect vector p to base.x, the fit this effect is added to.
        """
        return [probe.x(np.zeros(self.size))]

    def penalty(self, p, d) -> list[float]:
        """Extra constraint rows (relative units) appended to the whitened residual when the
        inertia's scale is pinned (d.scale_fixed).
        """
        return []

    # --- truth ------------------------------------------------------------------------------
    def disturbance(self, params: dict) -> dict:
        """Fields of dynamics.Disturbance that carry this effect in the compiled right-hand side."""
        return {}

    def applied(self, params: dict, tau: np.ndarray, dt: float) -> np.ndarray:
        """Torque (n, 3) N·m the body receives from the commanded torque tau (n, 3)."""
        return tau

    def gyro(self, params: dict, w: np.ndarray) -> np.ndarray:
        """Noise-free gyro output (n, 3) from true rates w (n, 3)."""
        return w

    def true_inertia(self, params: dict):
        """The body's true inertia (3, 3) when this effect sets it (not the nominal), or None."""
        return None

    def body_torque(self, params: dict, w: np.ndarray, inertia: np.ndarray):
        """Extra body torque (3,) N·m at rate w (3,) that the hook cannot carry, or None."""
        return None

    # --- equation error (fit.residual / fit.whitener) ------------------------------------------
    def rates(self, p, w: np.ndarray, gain: np.ndarray):
        """Gyro reading -> corrected rates (n, 3), and the gain (3,) of d w_true / d w_read."""
        return w, gain

    def inertia_step(self, p, d):
        """(after (n,) bool, delta_J (3, 3)): an inertia added from some time on, or None."""
        return None

    def modal_momentum(self, p, d, w: np.ndarray):
        """Extra momentum (n, 3) N·m·s that is differentiated with J w, or None."""
        return None

    def noise_inertia(self, p):
        """(3, 3) kg·m² subtracted from J in the noise path, or None."""
        return None

    def actuate(self, p, d, tau: np.ndarray) -> np.ndarray:
        """Commanded torque (n, 3) -> the torque the model applies."""
        return tau

    def torque(self, p, d, w, jw, jm):
        """External torque (n, 3) N·m on the body in the model (w corrected, jw = J(t) w), or None."""
        return None


#: Effect name -> its model; the catalogue in the contract's order.
REGISTRY: dict[str, EffectModel] = {}


def register(cls):
    """Class decorator: add one instance of an EffectModel subclass to REGISTRY."""
    REGISTRY[cls.name] = cls()
    return cls


@register
class GyroBias(EffectModel):
    """Gyro reads w + b (b rad/s per axis)."""

    name, params, size = "gyro_bias", ("bias",), 3

    @override
    def draw(self, rng, body):
        return {"bias": _signed(rng, 3.0, 10.0, 3) * body.gyro_sigma}

    @override
    def gyro(self, params, w):
        return w + np.asarray(params["bias"], float)

    @override
    def rates(self, p, w, gain):
        return w - p, gain


@register
class GyroScale(EffectModel):
    """Gyro reads (1 + s) w, s per axis."""

    name, params, size = "gyro_scale", ("scale",), 3
    # A common gyro scale s and a torque scale coincide only while the gyroscopic term w x Jw is
    # negligible beside the torque (J w_dot / (1+s) vs w x Jw / (1+s)^2): on a spinning body they
    # separate, and where they do not, their delta BICs are close and the gap rule reports it.
    ambiguities = (("inertia", "a common gyro scale is not identifiable without torque or attitude "
                    "(only per-axis differences are)"),)

    @override
    def draw(self, rng, body):
        return {"scale": _signed(rng, 0.01, 0.05, 3)}

    @override
    def bounds(self, d):
        return np.full(3, -0.5), np.full(3, np.inf)  # a reading at least half the true rate

    @override
    def gyro(self, params, w):
        return w * (1.0 + np.asarray(params["scale"], float))

    @override
    def rates(self, p, w, gain):
        g = 1.0 / (1.0 + p)
        return w * g, gain * g


@register
class ConstantBodyTorque(EffectModel):
    """A constant torque fixed in the body (N·m)."""

    name, params, size = "constant_body_torque", ("torque",), 3

    @override
    def draw(self, rng, body):
        return {"torque": _unit(rng) * rng.uniform(0.03, 0.1) * body.tau_ref}

    @override
    def disturbance(self, params):
        return {"constant_torque": tuple(np.asarray(params["torque"], float))}

    @override
    def torque(self, p, d, w, jw, jm):
        return np.broadcast_to(p, w.shape)


@register
class InternalMomentum(EffectModel):
    """A constant stored momentum h (kg·m²/s, body frame): w x (J w + h)."""

    name, params, size = "internal_momentum", ("h",), 3

    @override
    def draw(self, rng, body):
        return {"h": _unit(rng) * rng.uniform(0.02, 0.08) * body.j * body.omega_ref}

    @override
    def disturbance(self, params):
        return {"internal_momentum": tuple(np.asarray(params["h"], float))}

    @override
    def torque(self, p, d, w, jw, jm):
        return -np.cross(w, p)


@register
class ViscousDamping(EffectModel):
    """Torque -C w with C diagonal (N·m·s)."""

    name, params, size = "viscous_damping", ("c_diag",), 3
    ambiguities = (("aero_drag", "-C w and -c|w| w coincide while |w| stays nearly constant"),)

    @override
    def draw(self, rng, body):
        return {"c_diag": rng.uniform(0.004, 0.015, 3) * body.j}

    @override
    def disturbance(self, params):
        return {"damping": tuple(map(tuple, np.diag(np.asarray(params["c_diag"], float))))}

    @override
    def torque(self, p, d, w, jw, jm):
        return -p * w


@register
class AeroDrag(EffectModel):
    """Torque -c |w| w (N·m·s²)."""

    name, params, size = "aero_drag", ("c",), 1
    ambiguities = (("viscous_damping", "-C w and -c|w| w coincide while |w| stays nearly constant"),)

    @override
    def draw(self, rng, body):
        return {"c": rng.uniform(0.004, 0.015) * body.j / body.omega_ref}

    @override
    def disturbance(self, params):
        return {"aero_drag": float(params["c"])}

    @override
    def torque(self, p, d, w, jw, jm):
        return -p[0] * np.linalg.norm(w, axis=1, keepdims=True) * w


@register
class InternalDissipation(EffectModel):
    """Torque -d (w - u (u . w)), u = J w / |J w|: energy decays, |J w| is kept (N·m·s)."""

    name, params, size = "internal_dissipation", ("d",), 1

    @override
    def draw(self, rng, body):
        return {"d": rng.uniform(0.01, 0.04) * body.j}

    @override
    def body_torque(self, params, w, inertia):
        hh = inertia @ w
        u = hh / np.linalg.norm(hh)
        return -float(params["d"]) * (w - u * (u @ w))

    @override
    def torque(self, p, d, w, jw, jm):
        u = jw / np.linalg.norm(jw, axis=1, keepdims=True)
        return -p[0] * (w - u * np.sum(u * w, axis=1, keepdims=True))


@register
class ActuatorScale(EffectModel):
    """The body receives (1 + s) times the commanded torque."""

    name, params, size = "actuator_scale", ("scale",), 1
    needs_torque = True
    ambiguities = (("inertia", "the torque scale is measured against the sidecar's nominal "
                    "inertia: J/s with torque tau fits as well as J with torque s*tau, so a wrong "
                    "nominal trace reads as an actuator scale"),)

    @override
    def skip_reason(self, d):
        if not d.scale_fixed:
            return ("indistinguishable from the inertia's scale: no nominal inertia in the sidecar "
                    "to pin it")
        return super().skip_reason(d)

    @override
    def draw(self, rng, body):
        return {"scale": float(_signed(rng, 0.2, 0.5))}

    @override
    def applied(self, params, tau, dt):
        return tau * (1.0 + float(params["scale"]))

    @override
    def actuate(self, p, d, tau):
        return tau * (1.0 + p[0])


@register
class ActuatorMisalignment(EffectModel):
    """The commanded torque is rotated by a rotation vector (rad)."""

    name, params, size = "actuator_misalignment", ("rotvec",), 3
    needs_torque = True

    @override
    def draw(self, rng, body):
        return {"rotvec": _unit(rng) * np.deg2rad(rng.uniform(10.0, 25.0))}

    @override
    def applied(self, params, tau, dt):
        return tau @ rotvec_matrix(params["rotvec"]).T

    @override
    def actuate(self, p, d, tau):
        return tau @ rotvec_matrix(p).T


@register
class ActuatorDelay(EffectModel):
    """The commanded torque arrives delay seconds late."""

    name, params, size = "actuator_delay", ("delay",), 1
    needs_torque = True

    @override
    def draw(self, rng, body):
        return {"delay": rng.uniform(0.2, 0.6)}

    @override
    def starts(self, d, base, probe):
        return [probe.x(np.array([v])) for v in np.arange(0.05, 1.0, 0.1)]

    @override
    def applied(self, params, tau, dt):
        n = tau.shape[0]
        lo = np.floor(np.arange(n) - float(params["delay"]) / dt).astype(int)
        return np.where((lo >= 0)[:, None], tau[np.clip(lo, 0, n - 1)], 0.0)

    @override
    def actuate(self, p, d, tau):
        idx = np.searchsorted(d.t, d.t - p[0], side="right") - 1
        return np.where((idx >= 0)[:, None], tau[np.clip(idx, 0, None)], 0.0)


@register
class GravityGradient(EffectModel):
    """Torque 3 n^2 r x J r, r the inertial nadir in the body frame; fitted as n * nadir (3,)."""

    name, params, size = "gravity_gradient", ("orbit_rate", "nadir_inertial"), 3
    needs_attitude = True

    @override
    def draw(self, rng, body):
        # Sized by its signature on the gyro, not by the actuator level: the gradient torque
        # 3 n^2 r x J r is fixed in the orbit frame, so a body tumbling at omega_ref sees it turn
        # at about 2 omega_ref and its rates move by only ~ torque / (j 2 omega_ref). At the
        # paper's 10 rad/s spin, 3-10 % of a 50 N·m tau_ref is at most a tenth of a 0.03 rad/s
        # gyro noise: not identifiable (on 60-s recordings the model at the true parameters
        # scored below the nominal one). The peak torque is drawn so that signature is 1-3 gyro
        # sigmas (gyro_bias / gyro_scale are drawn at 3-17 sigmas), never below 3-10 % of
        # tau_ref, which is what a slow tumble (little averaging) needs; at 10 rad/s that is a
        # few % of the body's own gyroscopic torque omega^2 (J_max - J_min): visible, not dominant.
        # Its orbit_rate is then a torque-level knob (the truth holds the nadir fixed).
        j = body.j
        spread = max(float(np.ptp(np.linalg.eigvalsh(body.inertia))), 1e-3 * j)
        seen = rng.uniform(1.0, 3.0) * body.gyro_sigma * j * 2.0 * body.omega_ref
        torque = max(seen, rng.uniform(0.03, 0.1) * body.tau_ref)
        return {"orbit_rate": float(np.sqrt(torque / (3.0 * spread))), "nadir_inertial": _unit(rng)}

    @override
    def unpack(self, p):
        n = np.linalg.norm(p[:3])
        return {"orbit_rate": n, "nadir_inertial": p[:3] / n if n > 0 else p[:3]}

    @override
    def pack(self, params):
        nadir = np.asarray(params["nadir_inertial"], float)
        return float(params["orbit_rate"]) * nadir / np.linalg.norm(nadir)

    @override
    def starts(self, d, base, probe):
        return [probe.x(0.02 * c) for c in np.vstack([np.eye(3), -np.eye(3)])]

    @override
    def disturbance(self, params):
        return {"orbit_rate": float(params["orbit_rate"]),
                "nadir_inertial": tuple(np.asarray(params["nadir_inertial"], float))}

    @override
    def torque(self, p, d, w, jw, jm):
        r = np.einsum("nji,j->ni", d.rot, p)
        return 3.0 * np.cross(r, r @ jm.T)


@register
class FlexibleMode(EffectModel):
    """One lightly damped mode (omega_n rad/s, zeta, coupling d (3,) sqrt(kg)·m) coupled to w_dot."""

    name, params, size = "flexible_mode", ("omega_n", "zeta", "coupling"), 5
    start_nfev = 8  # a short run from each screened start, then the best one to convergence

    @override
    def draw(self, rng, body):
        return {"omega_n": 2 * np.pi * rng.uniform(0.5, 2.0), "zeta": rng.uniform(0.01, 0.05),
                "coupling": _unit(rng) * np.sqrt(rng.uniform(0.02, 0.06) * body.j)}

    @override
    def unpack(self, p):  # the model depends on delta delta^T: report delta's sign canonically
        c = p[2:5] * (1.0 if p[2 + int(np.argmax(np.abs(p[2:5])))] >= 0 else -1.0)
        return {"omega_n": abs(p[0]), "zeta": abs(p[1]), "coupling": c}

    @override
    def pack(self, params):
        return np.r_[float(params["omega_n"]), float(params["zeta"]),
                     np.asarray(params["coupling"], float)]

    @override
    def bounds(self, d):  # a mode inside the sampled band, damping in [0, 1]
        dt = float(np.median(np.diff(d.t)))
        lb, ub = np.full(5, -np.inf), np.full(5, np.inf)
        lb[:2] = 2 * np.pi * 0.5 * FLEX_BAND[0], 0.0
        ub[:2] = 2 * np.pi * 0.5 / dt * 0.95, 1.0
        return lb, ub

    @override
    def starts(self, d, base, probe):
        return probe.flex_screen()

    @override
    def modal_momentum(self, p, d, w):
        dt = float(np.median(np.diff(d.t)))
        (_, _), (_, _), (b2, a2) = flex_filters(abs(p[0]) + 1e-9, abs(p[1]), dt)
        eta_d = -signal.lfilter(b2, a2, w - w[0], axis=0) @ p[2:5]  # s^2 H applied to w = s H w_dot
        return np.outer(eta_d, p[2:5])

    @override
    def noise_inertia(self, p):
        # The modal momentum delta eta_dot = -delta s^2 H (delta . w) passes the gyro's white
        # noise at gain 1 (s^2 H -> 1 above the mode): to the noise the body's inertia is
        # J - delta delta^T. Without this the fit could "explain" noise by growing delta.
        return np.outer(p[2:5], p[2:5])


@register
class InertiaChange(EffectModel):
    """At t_change (s) the inertia becomes J + delta_J (momentum kept); fitted at fixed trace."""

    name, params, size = "inertia_change", ("t_change", "delta_inertia"), 7

    @override
    def draw(self, rng, body):
        eig, vec = np.linalg.eigh(body.inertia)
        new = eig * (1 + _signed(rng, 0.05, 0.15, 3))
        new *= eig.sum() / new.sum()  # a redistribution (deployment, fuel moving) at fixed trace
        return {"t_change": rng.uniform(0.3, 0.7) * body.duration,
                "delta_inertia": (vec @ np.diag(new) @ vec.T - np.asarray(body.inertia)).tolist()}

    @override
    def unpack(self, p):
        return {"t_change": p[0], "delta_inertia": inertia_from_theta(p[1:7])}

    @override
    def pack(self, params):
        dj = np.asarray(params["delta_inertia"], float)
        return np.r_[float(params["t_change"]), dj[0, 0], dj[0, 1], dj[0, 2], dj[1, 1], dj[1, 2],
                     dj[2, 2]]

    @override
    def skip_reason(self, d):
        return "recording too short to split" if d.edges.size < 12 else None

    @override
    def held(self, d):
        return np.r_[True, np.zeros(6, bool)]  # t_change is set by the scan in starts()

    @override
    def starts(self, d, base, probe):
        """Scan t_change over the interval edges (inertia and delta_J solved for each), then on a
        finer grid around the best; the solver then refines the rest at that t_change.
        """
        free = np.r_[False, np.ones(6, bool)]
        best = min((probe.affine(np.r_[tc, np.zeros(6)], free)
                    for tc in d.t[d.edges[2:-2:max(1, (d.edges.size - 4) // 40)]]),
                   key=lambda cx: cx[0])
        step = max(1, (d.edges[1] - d.edges[0]) // 8)
        i0 = int(np.searchsorted(d.t, probe.effect_part(best[1])[0]))
        span = 2 * (d.edges[1] - d.edges[0])
        for i in range(max(1, i0 - span), min(d.t.size - 1, i0 + span), step):
            cand = probe.affine(np.r_[d.t[i], probe.effect_part(best[1])[1:]], free)
            if cand[0] < best[0]:
                best = cand
        return [best[1]]

    @override
    def penalty(self, p, d):
        return [(p[1] + p[4] + p[6]) / d.trace0]  # a redistribution at fixed trace

    @override
    def inertia_step(self, p, d):
        return d.t >= p[0], inertia_from_theta(p[1:7])


@register
class InertiaOffset(EffectModel):
    """The body's inertia differs from the sidecar's nominal, including its overall scale.

    Every model already fits J's shape with its trace pinned to the nominal's (fit.py); this
    effect frees the trace too, with J in the positive-definite log-Cholesky parameterization
    p = phi (estimation.inertia_param): never indefinite. The comparison of the fitted J with
    the nominal (% per principal moment, axis rotation) is report.inertia_comparison.
    """

    name, params, size = "inertia_offset", ("inertia",), 6
    sets_inertia = True
    ambiguities = (("actuator_scale", "the inertia's overall scale trades against the torque "
                    "scale (c J with torque c tau fits the same): only the shape of J, its moment "
                    "ratios and principal axes, is told apart from an actuator scale"),)

    @override
    def skip_reason(self, d):
        if d.inertia0 is None:
            return "no inertia_nominal in the sidecar: the inertia is fitted in every model"
        if not d.has_torque:
            return ("no commanded torque: the inertia's scale is not seen, and its shape is "
                    "fitted in every model")
        return None

    @override
    def draw(self, rng, body):
        eig, vec = np.linalg.eigh(body.inertia)
        moments = eig * (1 + _signed(rng, 0.05, 0.15, 3))
        turn = rotvec_matrix(_unit(rng) * np.deg2rad(rng.uniform(3.0, 10.0)))
        axes = turn @ vec
        return {"inertia": axes @ np.diag(moments) @ axes.T}

    @override
    def unpack(self, p):
        return {"inertia": inertia_from_phi(p)}

    @override
    def pack(self, params):
        return phi_from_inertia(params["inertia"])

    @override
    def starts(self, d, base, probe):
        inertia = base.inertia
        if not np.all(np.linalg.eigvalsh(inertia) > 0):  # an indefinite nominal: start isotropic
            inertia = np.eye(3) * max(d.trace0, 1e-12) / 3.0
        return [probe.x(phi_from_inertia(inertia))]

    @override
    def true_inertia(self, params):
        return np.asarray(params["inertia"], float)

    @override
    def inertia(self, p):
        return inertia_from_phi(p)


def effect_model(name: str) -> EffectModel:
    """The registered model of an effect name (ConfigError naming the choices otherwise)."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ConfigError(f"unknown effect {name!r}; choose from {sorted(REGISTRY)}") from None


#: Effect name -> ordered parameter names (vector parameters are given as 3-lists).
EFFECTS: dict[str, tuple[str, ...]] = {name: m.params for name, m in REGISTRY.items()}


@dataclasses.dataclass(frozen=True)
class Effect:
    """One catalogue effect with its parameters (a dict of floats / lists): a truth instance."""

    name: str
    params: dict

    def __post_init__(self) -> None:
        model = effect_model(self.name)
        unknown = set(self.params) - set(model.params)
        if unknown:
            raise ConfigError(f"effect {self.name}: unknown parameter(s) {sorted(unknown)}; "
                              f"expected {model.params}")

    @property
    def model(self) -> EffectModel:
        """The effect's registered class instance."""
        return REGISTRY[self.name]


def random_params(name: str, rng: np.random.Generator, inertia, omega_ref: float, tau_ref: float,
                  gyro_sigma: float, duration: float) -> dict:
    """Random magnitudes of an effect sized to the body (see Body and each class's draw).

    inertia (3, 3) kg·m², omega_ref rad/s (typical rate), tau_ref N·m (actuator level),
    gyro_sigma rad/s, duration s.
    """
    body = Body(np.asarray(inertia, float), omega_ref, tau_ref, gyro_sigma, duration)
    return effect_model(name).draw(rng, body)
