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
    gyro_reading,
    jsonable,
    random_params,
    simulate_truth,
)
from inertia_gym.discrepancy.recordings import Recording
from inertia_gym.dynamics import euler_to_quat
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario


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


def simulate_recording(scenario: Scenario, duration: float, effect_name: str | None = None,
                       overrides: dict | None = None, seed: int = 0, torque: bool = True,
                       sample_dt: float | None = None,
                       rotor_h_max: float | None = None) -> tuple[Recording, dict]:
    """A noisy recording of the scenario's body with one effect (random magnitudes by default).

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
    effect = None
    if effect_name is not None:
        params = random_params(effect_name, rng, inertia, float(np.linalg.norm(scenario.omega0)),
                               scenario.tau_max, scenario.gyro_sigma, duration)
        params.update(overrides or {})
        effect = Effect(effect_name, params)
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
                          inertia, tau, dt, effect, momentum)
    gyro = gyro_reading(w[idx], effect) + gyro_noise
    qm = q[idx] + quat_noise
    qm /= np.linalg.norm(qm, axis=1, keepdims=True)
    qm *= np.sign(qm[:, :1] + 1e-300)
    tau_rows = np.vstack([tau, tau[-1:]])[idx]
    sidecar = {
        "inertia_nominal": inertia.tolist(), "gyro_sigma": scenario.gyro_sigma,
        "quat_sigma": scenario.quat_sigma, "seed": seed,
        "effect": None if effect is None else {"name": effect.name, "params": jsonable(effect.params)},
    }
    if rotor_h_max is not None:
        sidecar["rotor"] = {"h_max": float(rotor_h_max), "axis": axis.tolist(),
                            "profile": "h(t) = h_max * 0.5 * (1 - cos(2 pi t / duration)) * axis",
                            "duration": float(duration)}
    rec = Recording(idx * dt, gyro, qm, tau_rows if torque else None, sidecar, "simulated", h=h_rows)
    return rec, sidecar
