"""Synthetic recordings: the truth simulator, sensors, and a torque-burst schedule.

The effect's truth goes only to the sidecar (`effect` with `name`, `params`); the recording
itself looks like any hardware log.
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
                       sample_dt: float | None = None) -> tuple[Recording, dict]:
    """A noisy recording of the scenario's body with one effect (random magnitudes by default).

    duration s; sample_dt s (gyro/attitude rows, default the scenario's dt, a multiple of it).
    Returns the recording and its sidecar dict (inertia_nominal, noise levels, effect truth).
    """
    if not (np.isfinite(duration) and duration > 0):
        raise ConfigError(f"--duration must be a positive number of seconds, got {duration}")
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
    q, w = simulate_truth(euler_to_quat(scenario.attitude0_euler_deg), np.asarray(scenario.omega0),
                          inertia, tau, dt, effect)
    idx = np.arange(0, n + 1, every)
    gyro = gyro_reading(w[idx], effect) + rng.normal(0.0, scenario.gyro_sigma, (idx.size, 3))
    qm = q[idx] + rng.normal(0.0, scenario.quat_sigma, (idx.size, 4))
    qm /= np.linalg.norm(qm, axis=1, keepdims=True)
    qm *= np.sign(qm[:, :1] + 1e-300)
    tau_rows = np.vstack([tau, tau[-1:]])[idx]
    sidecar = {
        "inertia_nominal": inertia.tolist(), "gyro_sigma": scenario.gyro_sigma,
        "quat_sigma": scenario.quat_sigma, "seed": seed,
        "effect": None if effect is None else {"name": effect.name, "params": jsonable(effect.params)},
    }
    rec = Recording(idx * dt, gyro, qm, tau_rows if torque else None, sidecar, "simulated")
    return rec, sidecar
