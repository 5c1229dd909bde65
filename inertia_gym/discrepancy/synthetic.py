"""Synthetic recordings: the truth simulator, sensors, a torque-burst schedule and a rotor.

The effect's truth goes only to the sidecar (`effect` with `name`, `params`); the recording
itself looks like any hardware log. An optional rotor (a known internal angular momentum that
spins up and down along a fixed body axis) is written as the h_x, h_y, h_z columns, its truth
to the sidecar's `rotor` (`h_max`, `axis`).
"""

from __future__ import annotations

import numpy as np

from inertia_gym.discrepancy.effects import (
    EFFECTS,
    Effect,
    EffectModel,
    jsonable,
    random_params,
)
from inertia_gym.discrepancy.recordings import Recording
from inertia_gym.dynamics import Disturbance, euler_to_quat, inv3, propagate, state_rate
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario


def _effects_tuple(effects) -> tuple[Effect, ...]:
    if effects is None:
        return ()
    return (effects,) if isinstance(effects, Effect) else tuple(effects)


def simulate_truth(q0, omega0, inertia, torque_cmd, dt: float, effects=(), momentum=None):
    """Integrate the true body with the given effects (RK4, step dt) on dynamics.state_rate.

    q0 (4,), omega0 (3,) rad/s, inertia (3, 3), torque_cmd (n, 3) N·m held over each step;
    effects: an Effect, a sequence of them (a compound truth) or None. Each effect's class sets
    its terms: the commanded torque is transformed (actuator effects), the disturbance hook of
    dynamics.state_rate carries the body torques it knows (constant torque, stored momentum,
    damping, drag, gravity gradient), an inertia change restarts at t_change with the momentum
    kept (J1 w1 = J2 w2). Only a torque the hook cannot carry (internal dissipation), a flexible
    mode (two more states) or a known internal momentum varying in time take the augmented RK4
    below, whose rigid part is still dynamics.state_rate.
    momentum: None, or a known internal angular momentum relative to the body (reaction wheels,
    a rotor) as a function t (s) -> (h (3,) kg·m²/s, h_dot (3,) N·m), body frame; the body then
    obeys J w_dot = tau - h_dot - w x (J w + h) (plus the effects' terms), evaluated at each RK4
    stage time.
    Returns q (n+1, 4), omega (n+1, 3) — the body's true rates (sensor effects not applied).
    """
    effects = _effects_tuple(effects)
    inertia = np.asarray(inertia, float)
    for e in effects:  # inertia_offset: the body is not the nominal one
        true = e.model.true_inertia(e.params)
        inertia = inertia if true is None else true
    applied = np.asarray(torque_cmd, float)
    fields: dict = {}
    for e in effects:
        applied = e.model.applied(e.params, applied, dt)
        hook = e.model.disturbance(e.params)
        if set(hook) & set(fields):
            raise ConfigError(f"effects {[x.name for x in effects]} set the same disturbance term")
        fields.update(hook)
    dist = Disturbance(**fields).pack()
    n = applied.shape[0]
    k_change, j_after = n, inertia
    for e in effects:
        if e.name == "inertia_change":
            after = np.flatnonzero(np.arange(n) * dt >= float(e.params["t_change"]))
            k_change = int(after[0]) if after.size else n
            j_after = inertia + np.asarray(e.params["delta_inertia"], float)
    extra = [e for e in effects if type(e.model).body_torque is not EffectModel.body_torque]
    flex = next((e for e in effects if e.name == "flexible_mode"), None)
    y0 = np.concatenate([np.asarray(q0, float), np.asarray(omega0, float)])
    if not extra and flex is None and momentum is None:
        q1, w1 = propagate(y0[:4], y0[4:], inertia, applied[:k_change], dt, dist)
        if k_change == n:
            return q1, w1
        q2, w2 = propagate(q1[-1], np.linalg.solve(j_after, inertia @ w1[-1]), j_after,
                           applied[k_change:], dt, dist)
        return np.vstack([q1, q2[1:]]), np.vstack([w1, w2[1:]])
    return _augmented_rk4(y0, inertia, j_after, k_change, applied, dt, dist, extra, flex, momentum)


def _augmented_rk4(y0, inertia, j_after, k_change, applied, dt, dist, extra, flex, momentum):
    """RK4 of (q, w, eta, eta_dot): the rigid rate a = dynamics.state_rate with the stored
    momentum h + h_known(t) + delta eta_dot in the hook and tau - h_known_dot + extra torques;
    a flexible mode then solves J w_dot + delta eta_ddot = J a with the modal equation
    eta_ddot + delta . w_dot = -2 zeta Omega eta_dot - Omega^2 eta in closed form.
    """
    delta = np.asarray(flex.params["coupling"], float) if flex else np.zeros(3)
    om = float(flex.params["omega_n"]) if flex else 0.0
    ze = float(flex.params["zeta"]) if flex else 0.0
    h_hook = dist[3:6].copy()

    def rate(y, tau, j, j_inv, t):
        w, eta, eta_d = y[4:7], y[7], y[8]
        d_t, tau_t = dist.copy(), tau.copy()
        h = h_hook + delta * eta_d
        if momentum is not None:
            h_known, h_known_dot = momentum(t)
            h = h + h_known
            tau_t = tau_t - h_known_dot
        for e in extra:
            tau_t = tau_t + e.model.body_torque(e.params, w, j)
        d_t[3:6] = h
        r = state_rate(y[0], y[1], y[2], y[3], w[0], w[1], w[2], j, j_inv, tau_t, d_t)
        a = np.array(r[4:])
        eta_dd = 0.0
        if flex is not None:
            jd = j_inv @ delta
            eta_dd = (-2 * ze * om * eta_d - om * om * eta - delta @ a) / (1.0 - delta @ jd)
            a = a - jd * eta_dd
        return np.concatenate([r[:4], a, [eta_d, eta_dd]])

    y = np.concatenate([y0, [0.0, 0.0]])
    n = applied.shape[0]
    out = np.empty((n + 1, 9))
    out[0] = y
    j, j_inv = inertia, inv3(inertia)
    for k in range(n):
        if k == k_change:
            y[4:7] = np.linalg.solve(j_after, inertia @ y[4:7])
            j, j_inv = j_after, inv3(j_after)
        tau, t = applied[k], k * dt
        k1 = rate(y, tau, j, j_inv, t)
        k2 = rate(y + 0.5 * dt * k1, tau, j, j_inv, t + 0.5 * dt)
        k3 = rate(y + 0.5 * dt * k2, tau, j, j_inv, t + 0.5 * dt)
        k4 = rate(y + dt * k3, tau, j, j_inv, t + dt)
        y = y + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        y[:4] /= np.linalg.norm(y[:4])
        out[k + 1] = y
    return out[:, :4], out[:, 4:7]


def gyro_reading(w, effects=()) -> np.ndarray:
    """Noise-free gyro output (n, 3) from true rates w (n, 3) under the effects' sensor terms."""
    for e in _effects_tuple(effects):
        w = e.model.gyro(e.params, w)
    return w


def burst_schedule(n: int, dt: float, tau_max: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) N·m: bursts of magnitude tau_max, random direction, 2-6 s on, 2-6 s off."""
    tau = np.zeros((n, 3))
    t = rng.uniform(1.0, 3.0)
    while t < n * dt:
        on = rng.uniform(2.0, 6.0)
        v = rng.normal(size=3)
        a, b = int(t / dt), int(min(t + on, n * dt) / dt)
        tau[a:b] = tau_max * v / np.linalg.norm(v)
        t += on + rng.uniform(2.0, 6.0)
    return tau


def rotor_profile(t, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Smooth spin-up then spin-down over the recording: 0.5 (1 - cos(2 pi t / duration)).

    t s (scalar or array), duration s. Returns the profile (0 at both ends, 1 mid-way) and its
    time derivative (1/s), each shaped like t.
    """
    phase = 2.0 * np.pi * np.asarray(t, float) / duration
    return 0.5 * (1.0 - np.cos(phase)), np.pi / duration * np.sin(phase)


def rotor_momentum(h_max: float, axis, duration: float):
    """Known internal momentum of a rotor: t (s) -> (h (3,) kg·m²/s, h_dot (3,) N·m), body frame.

    h(t) = h_max * rotor_profile(t) * axis, h_max kg·m²/s, axis (3,) a unit body-frame vector,
    duration s. This is the ``momentum`` argument of simulate_truth.
    """
    axis = np.asarray(axis, float)

    def momentum(t: float) -> tuple[np.ndarray, np.ndarray]:
        prof, prof_dot = rotor_profile(t, duration)
        return h_max * prof * axis, h_max * prof_dot * axis

    return momentum


def parse_effect(text: str | None) -> tuple[str | None, dict]:
    """'NAME[:key=value,...]' -> (name, overrides). Vector values use ';' (bias=0.1;0;0)."""
    if not text or text == "none":
        return None, {}
    name, _, rest = text.partition(":")
    if name not in EFFECTS:
        raise ConfigError(f"--effect: unknown effect {name!r}; choose from {sorted(EFFECTS)} or none")
    params = {}
    for item in filter(None, rest.split(",")):
        key, sep, value = item.partition("=")
        if not sep or key not in EFFECTS[name]:
            raise ConfigError(f"--effect {name}: expected key=value with key in {EFFECTS[name]}, "
                              f"got {item!r}")
        try:
            vals = [float(v) for v in value.split(";")]
        except ValueError:
            raise ConfigError(f"--effect {name}: {key} must be numbers, got {value!r}") from None
        params[key] = vals[0] if len(vals) == 1 else vals
    return name, params


def simulate_recording(scenario: Scenario, duration: float, effect_name: str | list | None = None,
                       overrides: dict | None = None, seed: int = 0, torque: bool = True,
                       sample_dt: float | None = None,
                       rotor_h_max: float | None = None) -> tuple[Recording, dict]:
    """A noisy recording of the scenario's body with one effect (random magnitudes by default).

    effect_name: None, a name, or a list of names (a compound truth: the sidecar's `effect` is
    the first, `effects` lists them all; overrides apply to the first).

    duration s; sample_dt s (gyro/attitude rows, default the scenario's dt, a multiple of it).
    rotor_h_max kg·m²/s: with a value, a rotor along a random fixed body axis carries the known
    momentum h(t) = rotor_h_max * rotor_profile(t) * axis; the truth includes it, the recording
    gets its h columns (exact, noise-free) and the sidecar its `rotor` truth. The axis is the
    seed's last draw, so every other output of a seed is the same with or without the rotor.
    Returns the recording and its sidecar dict (inertia_nominal, noise levels, effect truth).
    """
    if not (np.isfinite(duration) and duration > 0):
        raise ConfigError(f"--duration must be a positive number of seconds, got {duration}")
    if rotor_h_max is not None and not (np.isfinite(rotor_h_max) and rotor_h_max > 0):
        raise ConfigError(f"--rotor-momentum must be a positive number of kg·m²/s, got {rotor_h_max}")
    rng = np.random.default_rng(seed)
    dt = scenario.dt
    every = 1 if sample_dt is None else max(1, int(round(sample_dt / dt)))
    n = int(round(duration / dt))
    inertia = scenario.inertia_true_array
    tau = burst_schedule(n, dt, scenario.tau_max, rng) if torque else np.zeros((n, 3))
    effects = []
    for name in [] if effect_name is None else [effect_name] if isinstance(effect_name, str) \
            else list(effect_name):
        params = random_params(name, rng, inertia, float(np.linalg.norm(scenario.omega0)),
                               scenario.tau_max, scenario.gyro_sigma, duration)
        if not effects:
            params.update(overrides or {})
        effects.append(Effect(name, params))
    idx = np.arange(0, n + 1, every)
    # The noise is drawn before the truth is integrated (it depends only on the row count) so that
    # the rotor's axis can be the last draw: the same seed gives the same tau, effect and noise.
    gyro_noise = rng.normal(0.0, scenario.gyro_sigma, (idx.size, 3))
    quat_noise = rng.normal(0.0, scenario.quat_sigma, (idx.size, 4))
    momentum = h_rows = axis = None
    if rotor_h_max is not None:
        v = rng.normal(size=3)
        axis = v / np.linalg.norm(v)
        momentum = rotor_momentum(rotor_h_max, axis, duration)
        h_rows = rotor_h_max * rotor_profile(idx * dt, duration)[0][:, None] * axis + 0.0  # no -0
    q, w = simulate_truth(euler_to_quat(scenario.attitude0_euler_deg), np.asarray(scenario.omega0),
                          inertia, tau, dt, effects, momentum)
    gyro = gyro_reading(w[idx], effects) + gyro_noise
    qm = q[idx] + quat_noise
    qm /= np.linalg.norm(qm, axis=1, keepdims=True)
    qm *= np.sign(qm[:, :1] + 1e-300)
    tau_rows = np.vstack([tau, tau[-1:]])[idx]
    sidecar = {
        "inertia_nominal": inertia.tolist(), "gyro_sigma": scenario.gyro_sigma,
        "quat_sigma": scenario.quat_sigma, "seed": seed,
        "effect": {"name": effects[0].name, "params": jsonable(effects[0].params)} if effects else None,
    }
    if len(effects) > 1:
        sidecar["effects"] = [{"name": e.name, "params": jsonable(e.params)} for e in effects]
    if rotor_h_max is not None:
        sidecar["rotor"] = {"h_max": float(rotor_h_max), "axis": axis.tolist(),
                            "profile": "h(t) = h_max * 0.5 * (1 - cos(2 pi t / duration)) * axis",
                            "duration": float(duration)}
    rec = Recording(idx * dt, gyro, qm, tau_rows if torque else None, sidecar, "simulated", h=h_rows)
    return rec, sidecar
