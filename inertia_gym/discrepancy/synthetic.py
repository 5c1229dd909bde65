"""Synthetic recordings: the truth simulator, sensors, a torque-burst schedule and a rotor.

The effect's truth goes only to the sidecar (`effect` with `name`, `params`); the recording
itself looks like any hardware log. An optional rotor (a known internal angular momentum that
spins up and down along a fixed body axis) is written as the h_x, h_y, h_z columns, its truth
to the sidecar's `rotor` (`h_max`, `axis`).
"""

from __future__ import annotations

import numpy as np

from inertia_gym.discrepancy.effects import EFFECTS, Effect, jsonable, random_params
from inertia_gym.discrepancy.model import Grid, gyro_output, held_cumulative, model_terms, simulate
from inertia_gym.dynamics import euler_to_quat
from inertia_gym.errors import ConfigError
from inertia_gym.recordings import Recording
from inertia_gym.scenario import Scenario


def _effects_tuple(effects) -> tuple[Effect, ...]:
    if effects is None:
        return ()
    return (effects,) if isinstance(effects, Effect) else tuple(effects)


def simulate_truth(q0, omega0, inertia, torque_cmd, dt: float, effects=(), momentum=None):
    """Integrate the true body with the given effects (RK4, step dt) on dynamics.state_rate.

    q0 (4,), omega0 (3,) rad/s, inertia (3, 3), torque_cmd (n, 3) N·m held over each step;
    effects: an Effect, a sequence of them (a compound truth) or None. Each effect's class sets
    its terms (effects/): the commanded torque is transformed (actuator effects), the
    disturbance hook of dynamics.state_rate carries the body torques, a flexible mode and
    internal dissipation are added around it, an inertia change happens with the momentum kept
    (J1 w1 = J2 w2). This is the model diagnose fits (discrepancy.model), integrated by the one
    compiled augmented integrator, model_dynamics.propagate_model_batch.
    momentum: None, or a known internal angular momentum relative to the body (reaction wheels,
    a rotor) at t = 0, dt, ..., n dt, shape (n+1, 3) kg·m²/s, body frame, linear in between;
    the body then obeys J w_dot = tau - h_dot - w x (J w + h) (plus the effects' terms).
    Returns q (n+1, 4), omega (n+1, 3) — the body's true rates (sensor effects not applied).
    """
    torque_cmd = np.asarray(torque_cmd, float)
    n = torque_cmd.shape[0]
    t = np.arange(n + 1) * dt
    grid = Grid.of(t, np.ones(n, np.int64))
    rows = np.vstack([torque_cmd, torque_cmd[-1:]]) if n else np.zeros((1, 3))
    h = None if momentum is None else np.asarray(momentum, float)
    if h is not None and h.shape != (n + 1, 3):
        raise ConfigError(f"momentum must have shape ({n + 1}, 3), got {h.shape}")
    terms = model_terms(inertia, [(e.model, e.params) for e in _effects_tuple(effects)], grid,
                        held_cumulative(t, rows), h)
    y0 = np.concatenate([np.asarray(q0, float), np.asarray(omega0, float)])[None, None]
    out = simulate(grid, np.array([0, n]), y0, [terms])[0]
    return out[:, :4], out[:, 4:]


def gyro_reading(t, w, effects=()) -> np.ndarray:
    """Noise-free gyro output (n, 3) from true rates w (n, 3) at times t (n,) s under the
    effects' sensor terms.
    """
    return gyro_output([(e.model, e.params) for e in _effects_tuple(effects)], w, t)


def burst_schedule(n: int, dt: float, tau_max: float, rng: np.random.Generator, every: int = 1) -> np.ndarray:
    """(n, 3) N·m: bursts of magnitude tau_max, random direction, 2-6 s on, 2-6 s off.

    Bursts switch only at multiples of `every` steps (the recording's rows), so a recording that
    logs the command at its rows, held from each row on, logs exactly the torque that acted.
    """
    tau = np.zeros((n, 3))
    t = rng.uniform(1.0, 3.0)
    while t < n * dt:
        on = rng.uniform(2.0, 6.0)
        v = rng.normal(size=3)
        a, b = (int(x / (dt * every)) * every for x in (t, min(t + on, n * dt)))
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


def rotor_momentum(h_max: float, axis, duration: float, t) -> np.ndarray:
    """Known internal momentum of a rotor (k, 3) kg·m²/s, body frame, at times t (k,) s:
    h(t) = h_max * rotor_profile(t) * axis, h_max kg·m²/s, axis (3,) a unit body-frame vector,
    duration s. On the integration grid this is the ``momentum`` argument of simulate_truth.
    """
    return h_max * rotor_profile(t, duration)[0][:, None] * np.asarray(axis, float) + 0.0  # no -0


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
    The sidecar's inertia_nominal is the scenario's TRUE inertia (inertia_true; inertia_guess is
    not used): a wrong nominal is the `inertia_offset` effect's truth, or a sidecar edited after.
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
    tau = burst_schedule(n, dt, scenario.tau_max, rng, every) if torque else np.zeros((n, 3))
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
        momentum = rotor_momentum(rotor_h_max, axis, duration, np.arange(n + 1) * dt)
        h_rows = momentum[idx]
    q, w = simulate_truth(euler_to_quat(scenario.attitude0_euler_deg), np.asarray(scenario.omega0),
                          inertia, tau, dt, effects, momentum)
    gyro = gyro_reading(idx * dt, w[idx], effects) + gyro_noise
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


#: kg·m², a tennis racquet: pendulum-measured moments (20.7 ± 3.8, 18.8 ± 5.7, 1.39 ± 0.08 g·m²)
#: with the middle one raised within its error bar to 19.5, since as measured no body has them
#: (18.8 + 1.39 < 20.7); a thin, long body whose flip about the middle axis is the
#: intermediate-axis tumble
RACQUET = np.diag([20.7e-3, 19.5e-3, 1.39e-3])


def racquet_flip(every: int = 10, sidecar: bool = True) -> Recording:
    """1 s of a racquet flipping at 15 rad/s with quadratic air drag, gyro only (noise 5e-3
    rad/s, seed 0), simulated at 1 kHz and sampled every `every`-th step (100 Hz by default); the
    noise level in a sidecar (gyro_sigma), or with sidecar=False left for diagnose to read.
    """
    drag = Effect("aero_drag", {"c": np.diag([4e-5, 3e-5, 2e-6])})
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), np.array([0.3, 15.0, 0.4]), RACQUET,
                          np.zeros((1000, 3)), 1e-3, drag)
    idx = np.arange(0, 1001, every)
    noise = np.random.default_rng(0).normal(0, 0.005, (idx.size, 3))
    return Recording(idx * 1e-3, w[idx] + noise, None, None, {"gyro_sigma": 0.005} if sidecar else {},
                     "toss")
