"""The physics catalogue (docs/contracts.md): each effect's parameters, a random draw of them, the
truth simulator of the augmented system, and the equation-error model used to fit them.

Units: rad/s, N·m, kg·m², s. The body obeys
    J(t) w_dot + d eta_ddot + w x (J(t) w + h + d eta_dot) = tau_applied + tau_ext,
    eta_ddot + 2 zeta Omega eta_dot + Omega^2 eta = -d . w_dot          (flexible mode)
with the gyro reading (1 + s) * w + b. Every effect sets one group of these terms.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import signal

from inertia_gym.dynamics import quat_multiply, quat_to_rotation
from inertia_gym.errors import ConfigError

#: Effect name -> ordered parameter names (vector parameters are given as 3-lists).
EFFECTS: dict[str, tuple[str, ...]] = {
    "gyro_bias": ("bias",),
    "gyro_scale": ("scale",),
    "constant_body_torque": ("torque",),
    "internal_momentum": ("h",),
    "viscous_damping": ("c_diag",),
    "aero_drag": ("c",),
    "internal_dissipation": ("d",),
    "actuator_scale": ("scale",),
    "actuator_misalignment": ("rotvec",),
    "actuator_delay": ("delay",),
    "gravity_gradient": ("orbit_rate", "nadir_inertial"),
    "flexible_mode": ("omega_n", "zeta", "coupling"),
    "inertia_change": ("t_change", "delta_inertia"),
}
NEEDS_TORQUE = ("actuator_scale", "actuator_misalignment", "actuator_delay")
NEEDS_ATTITUDE = ("gravity_gradient",)


@dataclasses.dataclass(frozen=True)
class Effect:
    """One catalogue effect with its parameters (a dict of floats / lists)."""

    name: str
    params: dict

    def __post_init__(self) -> None:
        if self.name not in EFFECTS:
            raise ConfigError(f"unknown effect {self.name!r}; choose from {sorted(EFFECTS)}")
        unknown = set(self.params) - set(EFFECTS[self.name])
        if unknown:
            raise ConfigError(f"effect {self.name}: unknown parameter(s) {sorted(unknown)}; "
                              f"expected {EFFECTS[self.name]}")


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


def _unit(rng) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _signed(rng, lo, hi, size=None):
    return rng.uniform(lo, hi, size) * rng.choice([-1.0, 1.0], size)


def random_params(name: str, rng: np.random.Generator, inertia, omega_ref: float, tau_ref: float,
                  gyro_sigma: float, duration: float) -> dict:
    """Random magnitudes of an effect, sized to the body so it is visible but not dominant.

    inertia (3, 3) kg·m², omega_ref rad/s (typical rate), tau_ref N·m (actuator level),
    gyro_sigma rad/s, duration s.

    "Visible" means visible on the measured signals: sensor effects are drawn in gyro sigmas or
    as a share of the rate, body-fixed torques as a share of tau_ref (they accumulate), and the
    gravity gradient, which a tumble averages, by the rate signature it leaves on the gyro
    (torque / (j 2 omega_ref)): see the comment there. Its orbit_rate is then a torque-level knob
    (the truth simulator holds the nadir fixed), not a physical orbit.
    """
    j = float(np.trace(inertia)) / 3.0
    if name == "gyro_bias":
        return {"bias": _signed(rng, 3.0, 10.0, 3) * gyro_sigma}
    if name == "gyro_scale":
        return {"scale": _signed(rng, 0.01, 0.05, 3)}
    if name == "constant_body_torque":
        return {"torque": _unit(rng) * rng.uniform(0.03, 0.1) * tau_ref}
    if name == "internal_momentum":
        return {"h": _unit(rng) * rng.uniform(0.02, 0.08) * j * omega_ref}
    if name == "viscous_damping":
        return {"c_diag": rng.uniform(0.004, 0.015, 3) * j}
    if name == "aero_drag":
        return {"c": rng.uniform(0.004, 0.015) * j / omega_ref}
    if name == "internal_dissipation":
        return {"d": rng.uniform(0.01, 0.04) * j}
    if name == "actuator_scale":
        return {"scale": float(_signed(rng, 0.2, 0.5))}
    if name == "actuator_misalignment":
        return {"rotvec": _unit(rng) * np.deg2rad(rng.uniform(10.0, 25.0))}
    if name == "actuator_delay":
        return {"delay": rng.uniform(0.2, 0.6)}
    if name == "gravity_gradient":
        # Sized by its signature on the gyro, not by the actuator level: the gradient torque
        # 3 n^2 r x J r is fixed in the orbit frame, so a body tumbling at omega_ref sees it turn
        # at about 2 omega_ref and its rates move by only ~ torque / (j 2 omega_ref). At the
        # paper's 10 rad/s spin, 3-10 % of a 50 N·m tau_ref is at most a tenth of a 0.03 rad/s
        # gyro noise: not identifiable (on 60-s recordings the model at the true parameters
        # scored below the nominal one). The peak torque is drawn so that signature is 1-3 gyro
        # sigmas (gyro_bias / gyro_scale are drawn at 3-17 sigmas), never below 3-10 % of
        # tau_ref, which is what a slow tumble (little averaging) needs; at 10 rad/s that is a
        # few % of the body's own gyroscopic torque omega^2 (J_max - J_min): visible, not dominant.
        spread = max(float(np.ptp(np.linalg.eigvalsh(inertia))), 1e-3 * j)
        seen = rng.uniform(1.0, 3.0) * gyro_sigma * j * 2.0 * omega_ref
        torque = max(seen, rng.uniform(0.03, 0.1) * tau_ref)
        return {"orbit_rate": float(np.sqrt(torque / (3.0 * spread))), "nadir_inertial": _unit(rng)}
    if name == "flexible_mode":
        return {"omega_n": 2 * np.pi * rng.uniform(0.5, 2.0), "zeta": rng.uniform(0.01, 0.05),
                "coupling": _unit(rng) * np.sqrt(rng.uniform(0.02, 0.06) * j)}
    if name == "inertia_change":
        eig, vec = np.linalg.eigh(inertia)
        new = eig * (1 + _signed(rng, 0.05, 0.15, 3))
        new *= eig.sum() / new.sum()  # a redistribution (deployment, fuel moving) at fixed trace
        return {"t_change": rng.uniform(0.3, 0.7) * duration,
                "delta_inertia": (vec @ np.diag(new) @ vec.T - np.asarray(inertia)).tolist()}
    raise ConfigError(f"unknown effect {name!r}")


def jsonable(params: dict) -> dict:
    """Parameters with numpy values turned into floats / lists."""
    return {k: (np.asarray(v).tolist() if np.ndim(v) else float(v)) for k, v in params.items()}


# ------------------------------------------------------------------------------------------
# Truth simulator of the augmented system (rigid body + flexible mode + sensor/actuator effects)
# ------------------------------------------------------------------------------------------


def _truth_terms(effect: Effect | None):
    p = {} if effect is None else {k: np.asarray(v, float) for k, v in effect.params.items()}
    name = None if effect is None else effect.name
    return name, p


def simulate_truth(q0, omega0, inertia, torque_cmd, dt: float, effect: Effect | None = None,
                   momentum=None):
    """Integrate the true body with one effect (RK4, step dt).

    q0 (4,), omega0 (3,) rad/s, inertia (3, 3), torque_cmd (n, 3) N·m held over each step.
    momentum: None, or a known internal angular momentum relative to the body (reaction wheels,
    a rotor) as a function t (s) -> (h (3,) kg·m²/s, h_dot (3,) N·m), body frame; the body then
    obeys J w_dot = tau - h_dot - w x (J w + h) (plus the effect's terms), evaluated at each RK4
    stage time.
    Returns q (n+1, 4), omega (n+1, 3) — the body's true rates (sensor effects not applied).
    """
    name, p = _truth_terms(effect)
    inertia = np.asarray(inertia, float)
    n = torque_cmd.shape[0]
    applied = np.asarray(torque_cmd, float)
    if name == "actuator_scale":
        applied = applied * (1.0 + float(p["scale"]))
    elif name == "actuator_misalignment":
        applied = applied @ rotvec_matrix(p["rotvec"]).T
    elif name == "actuator_delay":
        shift = float(p["delay"]) / dt
        k = np.arange(n) - shift
        lo = np.floor(k).astype(int)
        applied = np.where((lo >= 0)[:, None], applied[np.clip(lo, 0, n - 1)], 0.0)
    flex = name == "flexible_mode"
    delta = p["coupling"] if flex else np.zeros(3)
    om, ze = (float(p["omega_n"]), float(p["zeta"])) if flex else (0.0, 0.0)
    h = p["h"] if name == "internal_momentum" else np.zeros(3)
    t_change = float(p["t_change"]) if name == "inertia_change" else np.inf
    j_after = inertia + np.asarray(p["delta_inertia"]) if name == "inertia_change" else inertia
    nadir = p["nadir_inertial"] / np.linalg.norm(p["nadir_inertial"]) if name == "gravity_gradient" else None

    def ext(q, w, j):
        if name == "constant_body_torque":
            return p["torque"]
        if name == "viscous_damping":
            return -p["c_diag"] * w
        if name == "aero_drag":
            return -float(p["c"]) * np.linalg.norm(w) * w
        if name == "internal_dissipation":
            hh = j @ w
            u = hh / np.linalg.norm(hh)
            return -float(p["d"]) * (w - u * (u @ w))
        if name == "gravity_gradient":
            r = quat_to_rotation(q).T @ nadir
            return 3.0 * float(p["orbit_rate"]) ** 2 * np.cross(r, j @ r)
        return np.zeros(3)

    def rate(y, tau, j, t):
        q, w, eta, eta_d = y[:4], y[4:7], y[7], y[8]
        if momentum is None:
            rhs_w = tau + ext(q, w, j) - np.cross(w, j @ w + h + delta * eta_d)
        else:
            h_known, h_known_dot = momentum(t)
            rhs_w = tau + ext(q, w, j) - h_known_dot - np.cross(w, j @ w + h + h_known + delta * eta_d)
        if flex:
            m = np.zeros((4, 4))
            m[:3, :3], m[:3, 3], m[3, :3], m[3, 3] = j, delta, delta, 1.0
            acc = np.linalg.solve(m, np.append(rhs_w, -2 * ze * om * eta_d - om * om * eta))
            w_dot, eta_dd = acc[:3], acc[3]
        else:
            w_dot, eta_dd = np.linalg.solve(j, rhs_w), 0.0
        q_dot = 0.5 * quat_multiply(q, np.array([0.0, w[0], w[1], w[2]]))
        return np.concatenate([q_dot, w_dot, [eta_d, eta_dd]])

    y = np.concatenate([np.asarray(q0, float), np.asarray(omega0, float), [0.0, 0.0]])
    out = np.empty((n + 1, 9))
    out[0] = y
    j = inertia
    for k in range(n):
        if k * dt >= t_change and j is inertia:
            j = j_after  # momentum kept through the change: J1 w1 = J2 w2
            y[4:7] = np.linalg.solve(j, inertia @ y[4:7])
        tau, t = applied[k], k * dt
        k1 = rate(y, tau, j, t)
        k2 = rate(y + 0.5 * dt * k1, tau, j, t + 0.5 * dt)
        k3 = rate(y + 0.5 * dt * k2, tau, j, t + 0.5 * dt)
        k4 = rate(y + dt * k3, tau, j, t + dt)
        y = y + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        y[:4] /= np.linalg.norm(y[:4])
        out[k + 1] = y
    return out[:, :4], out[:, 4:7]


def gyro_reading(w, effect: Effect | None) -> np.ndarray:
    """Noise-free gyro output (n, 3) from true rates w (n, 3) under sensor effects."""
    if effect is not None and effect.name == "gyro_bias":
        return w + np.asarray(effect.params["bias"], float)
    if effect is not None and effect.name == "gyro_scale":
        return w * (1.0 + np.asarray(effect.params["scale"], float))
    return w


# ------------------------------------------------------------------------------------------
# Equation-error model: e = J(t) w_dot + w x (J(t) w + h) - tau_applied - tau_ext  (N·m)
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Signals:
    """Smoothed, uniformly sampled signals the equation-error model is evaluated on.

    t (n,) s; w, w_dot (n, 3) gyro reading and its derivative; tau (n, 3) smoothed commanded
    torque (zeros when none); rot (n, 3, 3) body-to-inertial rotations or None; dt s.
    """

    t: np.ndarray
    w: np.ndarray
    w_dot: np.ndarray
    tau: np.ndarray
    rot: np.ndarray | None
    dt: float


def n_params(name: str | None) -> int:
    """Number of free parameters an effect adds to the inertia."""
    return {None: 0, "gyro_bias": 3, "gyro_scale": 3, "constant_body_torque": 3,
            "internal_momentum": 3, "viscous_damping": 3, "aero_drag": 1, "internal_dissipation": 1,
            "actuator_scale": 1, "actuator_misalignment": 3, "actuator_delay": 1,
            "gravity_gradient": 3, "flexible_mode": 5, "inertia_change": 7}[name]


def unpack(name: str | None, p: np.ndarray) -> dict:
    """Fitted parameter vector -> the catalogue's named parameters."""
    if name is None:
        return {}
    if name in ("gyro_bias",):
        return {"bias": p[:3]}
    if name == "gyro_scale":
        return {"scale": p[:3]}
    if name == "constant_body_torque":
        return {"torque": p[:3]}
    if name == "internal_momentum":
        return {"h": p[:3]}
    if name == "viscous_damping":
        return {"c_diag": p[:3]}
    if name in ("aero_drag",):
        return {"c": p[0]}
    if name == "internal_dissipation":
        return {"d": p[0]}
    if name == "actuator_scale":
        return {"scale": p[0]}
    if name == "actuator_misalignment":
        return {"rotvec": p[:3]}
    if name == "actuator_delay":
        return {"delay": p[0]}
    if name == "gravity_gradient":
        n = np.linalg.norm(p[:3])
        return {"orbit_rate": n, "nadir_inertial": p[:3] / n if n > 0 else p[:3]}
    if name == "flexible_mode":  # the model depends on delta delta^T: report delta's sign canonically
        c = p[2:5] * (1.0 if p[2 + int(np.argmax(np.abs(p[2:5])))] >= 0 else -1.0)
        return {"omega_n": abs(p[0]), "zeta": abs(p[1]), "coupling": c}
    if name == "inertia_change":
        d = p[1:7]
        return {"t_change": p[0], "delta_inertia": np.array([[d[0], d[1], d[2]], [d[1], d[3], d[4]],
                                                             [d[2], d[4], d[5]]])}
    raise ConfigError(f"unknown effect {name!r}")


def _flex_filters(omega_n: float, zeta: float, dt: float):
    """Discrete (bilinear) filters of 1/(s^2 + 2 zeta Omega s + Omega^2) times 1, s, s^2."""
    den = [1.0, 2 * zeta * omega_n, omega_n ** 2]
    return [signal.bilinear(num, den, fs=1.0 / dt) for num in ([1.0], [1.0, 0.0], [1.0, 0.0, 0.0])]


def equation_error(theta, name: str | None, p, sig: Signals) -> np.ndarray:
    """Residual torque (n, 3), N·m, of the rigid model with inertia theta (6,) and one effect."""
    jm = np.array([[theta[0], theta[1], theta[2]], [theta[1], theta[3], theta[4]],
                   [theta[2], theta[4], theta[5]]])
    w, w_dot, tau = sig.w, sig.w_dot, sig.tau
    if name == "gyro_bias":
        w = w - p[:3]
    elif name == "gyro_scale":
        w, w_dot = w / (1 + p[:3]), w_dot / (1 + p[:3])
    if name == "inertia_change":
        after = (sig.t >= p[0])[:, None]
        d = p[1:7]
        dj = np.array([[d[0], d[1], d[2]], [d[1], d[3], d[4]], [d[2], d[4], d[5]]])
        jw = w @ jm.T + after * (w @ dj.T)
        jwd = w_dot @ jm.T + after * (w_dot @ dj.T)
    else:
        jw, jwd = w @ jm.T, w_dot @ jm.T
    e = jwd + np.cross(w, jw)
    if name == "actuator_scale":
        tau = tau * (1 + p[0])
    elif name == "actuator_misalignment":
        tau = tau @ rotvec_matrix(p[:3]).T
    elif name == "actuator_delay":
        tau = np.stack([np.interp(sig.t - p[0], sig.t, tau[:, i], left=0.0) for i in range(3)], 1)
    e = e - tau
    if name == "constant_body_torque":
        e = e - p[:3]
    elif name == "internal_momentum":
        e = e + np.cross(w, p[:3])
    elif name == "viscous_damping":
        e = e + p[:3] * w
    elif name == "aero_drag":
        e = e + p[0] * np.linalg.norm(w, axis=1, keepdims=True) * w
    elif name == "internal_dissipation":
        u = jw / np.linalg.norm(jw, axis=1, keepdims=True)
        e = e + p[0] * (w - u * np.sum(u * w, axis=1, keepdims=True))
    elif name == "gravity_gradient":
        r = np.einsum("nji,j->ni", sig.rot, p[:3])
        e = e - 3.0 * np.cross(r, r @ jm.T)
    elif name == "flexible_mode":
        u = -(w_dot @ p[2:5])
        (b0, a0), (b1, a1), (b2, a2) = _flex_filters(abs(p[0]) + 1e-9, abs(p[1]), sig.dt)
        eta_d, eta_dd = signal.lfilter(b1, a1, u), signal.lfilter(b2, a2, u)
        e = e + np.outer(eta_dd, p[2:5]) + np.cross(w, np.outer(eta_d, p[2:5]))
    return e


def quat_rotations(q) -> np.ndarray:
    """(n, 4) unit quaternions -> (n, 3, 3) body-to-inertial rotation matrices."""
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)
