"""`InertiaGym/Excitation-v0`: one step is one excitation episode of Algorithm 1.

A thin Gymnasium shell over :func:`inertia_gym.episode.run_episode`; all physics, estimation
and the cost live there. The step of B runs (:func:`start_runs`, :func:`step_runs`,
:func:`observations`, :func:`step_info`) is written once for a batch: the single env steps a
batch of one, the native vector env (envs/vector.py) a batch of B.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from inertia_gym.episode import COSTS, EpisodeResult, run_episode
from inertia_gym.errors import ConfigError, InertiaGymError
from inertia_gym.scenario import Scenario
from inertia_gym.simulation import SimState, initial_state
from inertia_gym.validation import relative_error

OBS_SIZE = 16
# Finite observation bounds (observations are clipped into them): rates / |w0|, theta / s,
# log10 eigenvalues of P_theta / s², progress.
OBS_LOW = np.array([-100.0] * 3 + [-1000.0] * 6 + [-40.0] * 6 + [0.0], dtype=np.float32)
OBS_HIGH = np.array([100.0] * 3 + [1000.0] * 6 + [40.0] * 6 + [10.0], dtype=np.float32)


class ResetNeededError(InertiaGymError, gym.error.ResetNeeded):
    """`step` was called before `reset` (or after the run ended)."""


def as_scenario(scenario) -> Scenario:
    """A Scenario from a Scenario, a mapping of field overrides, a TOML/JSON path, or None."""
    if scenario is None or isinstance(scenario, Scenario):
        return Scenario() if scenario is None else scenario
    if isinstance(scenario, Mapping):
        return Scenario.from_mapping(scenario)
    if isinstance(scenario, (str, Path)):
        return Scenario.load(scenario)
    raise ConfigError(f"scenario must be a Scenario, a mapping of fields or a file path, got "
                      f"{type(scenario).__name__}")


def check_seed(seed: Any) -> int | None:
    """Return seed as an int; None passes; anything but an integer >= 0 raises ConfigError."""
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be None or an integer >= 0, got {seed!r}")
    return int(seed)


def check_cost(cost: Any) -> str:
    """Return cost if it is one of :data:`inertia_gym.episode.COSTS`, else raise ConfigError."""
    if cost not in COSTS:
        raise ConfigError(f"cost must be one of {COSTS}, got {cost!r}")
    return cost


def check_count(name: str, value: Any) -> int:
    """Return value as an int if it is an integer >= 1, else raise ConfigError naming `name`."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def divergence_cost(sc: Scenario, cost: str) -> float:
    """Finite cost charged for an episode in which the estimator diverged.

    info: -log(epsilon_lambda), the cost of an episode without any information (alpha = 0).
    posterior: 0, an episode that did not shrink the inertia posterior at all.
    """
    return float(-np.log(sc.epsilon_lambda)) if cost == "info" else 0.0


def action_to_xi(sc: Scenario, action) -> np.ndarray:
    """Map an action u in [-1, 1]^3 to xi = lo + (u + 1)/2 (hi - lo) (3,), checking u.

    Raises ConfigError for a wrong shape, NaN/inf, or a component outside [-1, 1] (beyond a
    float32 rounding tolerance of 1e-6).
    """
    u = np.asarray(action, dtype=float)
    if u.shape != (3,):
        raise ConfigError(f"action must have shape (3,), got {u.shape}")
    if not np.all(np.isfinite(u)):
        raise ConfigError(f"action must be finite, got {u.tolist()}")
    if np.any(np.abs(u) > 1.0 + 1e-6):
        raise ConfigError(f"action must lie in [-1, 1]^3 (a, b, T_on rescaled), got {u.tolist()}")
    lo, hi = sc.xi_bounds
    return lo + 0.5 * (np.clip(u, -1.0, 1.0) + 1.0) * (hi - lo)


def xi_to_action(sc: Scenario, xi) -> np.ndarray:
    """Inverse of :func:`action_to_xi`: xi (3,) -> u (3,) float32 in [-1, 1]."""
    lo, hi = sc.xi_bounds
    span = np.where(hi > lo, hi - lo, 1.0)
    return np.clip(2.0 * (np.asarray(xi, dtype=float) - lo) / span - 1.0, -1, 1).astype(np.float32)


def start_runs(sc: Scenario, rngs: list[np.random.Generator]) -> tuple[SimState, list[dict]]:
    """B runs at the scenario's start, one per Generator, and the reset info of each."""
    state = initial_state(sc, rngs)
    eigvals = np.linalg.eigvalsh(state.P_theta())
    errors = relative_error(state.inertia_hat(), sc.inertia_true_array)
    infos = [{"theta_hat": theta, "p_theta_eigvals": eig, "rel_error": float(err), "time": 0.0}
             for theta, eig, err in zip(state.theta_hat(), eigvals, errors)]
    return state, infos


@dataclasses.dataclass(frozen=True)
class Step:
    """One env step of B runs: state (the new SimState), results (one EpisodeResult per run),
    xi (B, 3) the actions as burst parameters, costs (B,).
    """

    state: SimState
    results: list
    xi: np.ndarray
    costs: np.ndarray


def step_runs(sc: Scenario, state: SimState, actions, rngs: list[np.random.Generator], *,
              cost: str, carry_over: bool) -> Step:
    """One env step of B runs: one excitation episode each, in one call of the batched loop.

    actions (B, 3) in [-1, 1], checked row by row (:func:`action_to_xi`); rngs: one Generator
    per run. With carry_over False every run first restarts from the scenario's start.
    The cost of a diverged run is :func:`divergence_cost`. The single env (B = 1) and the vector env
    both step through here.
    """
    xi = np.array([action_to_xi(sc, action) for action in actions]).reshape(-1, 3)
    if not carry_over:
        state = initial_state(sc, rngs)
    state, results = run_episode(sc, state, xi, rngs, cost=cost)
    costs = np.array([divergence_cost(sc, cost) if res.diverged else float(res.cost)
                      for res in results])
    return Step(state, results, xi, costs)


def observations(sc: Scenario, state: SimState, steps, budget: int) -> np.ndarray:
    """Observations (B, 16) float32 of B runs after `steps` (B,) steps out of `budget`.

    Layout and bounds as in :class:`ExcitationEnv`; a diverged run observes zeros.
    """
    obs = np.zeros((state.batch, OBS_SIZE), dtype=np.float32)
    healthy = np.flatnonzero(~state.diverged)
    if healthy.size == 0:
        return obs
    live = state.select(healthy)
    scale = float(np.trace(sc.inertia_guess_array) / 3.0)
    eig = np.linalg.eigvalsh(live.P_theta()) / scale**2
    features = np.concatenate([
        live.x[:, 4:7] / sc.omega_ref,
        live.theta_hat() / scale,
        np.log10(np.clip(eig, 1e-300, None)),
        np.asarray(steps, dtype=float)[healthy, None] / budget,
    ], axis=1)
    obs[healthy] = np.clip(np.nan_to_num(features), OBS_LOW, OBS_HIGH)
    return obs


def step_info(sc: Scenario, res: EpisodeResult, xi: np.ndarray, cost: float, time: float) -> dict:
    """The info dict of one run's step on `sc` (keys as in :class:`ExcitationEnv`); time s since
    reset. The limits are None where the scenario sets none.
    """
    return {
        "cost": cost,
        "info_cost": float(res.info_cost),
        "posterior_cost": float(res.posterior_cost),
        "alpha": float(res.alpha),
        "lambda_min": float(res.lambda_min.min()) if res.lambda_min.size else 0.0,
        "theta_hat": res.theta_hat,
        "p_theta_eigvals": res.p_theta_eigvals,
        "rel_error": float(res.rel_error),
        "xi": xi,
        "duration": float(res.duration),
        "time": time,
        "diverged": bool(res.diverged),
        "impulse": float(res.impulse),
        "impulse_demand": float(res.impulse_demand),
        "impulse_budget": sc.impulse_budget,
        "budget_spent": bool(res.budget_spent),
        "rate_peak": float(res.rate_peak),
        "rate_limit": sc.rate_limit,
        "rate_cuts": int(res.rate_cuts),
    }


class ExcitationEnv(gym.Env):
    """Informative torque excitation of a tumbling rigid body (Basu & Sanfelice, Algorithm 1).

    **Step.** One step is one excitation episode: N = ``scenario.bursts_per_episode`` bursts of
    the law tau = a (w_hat x v) + b v (eq. 18) of T_on seconds each, each followed by a dwell
    drawn from ``scenario.dwell`` (about 50 s of simulated time for the paper's scenario), while
    the truth, the noisy sensors and the EKF run. The estimator's state carries over to the next
    step (k0 advances), so a run of M steps is one run of Algorithm 1. With
    ``carry_over=False`` every step instead starts from the scenario's start (fresh noise from
    the same generator): a stationary noisy objective, the one ``evaluate_xi`` scores.

    **Action.** ``Box(-1, 1, (3,), float32)``, rescaled linearly to xi = (a, b, T_on) inside
    ``scenario.xi_bounds`` (paper: a in [0, tau_max/|w0|] N·m·s, b in [0, tau_max] N·m, T_on in
    [0.05, 1] s). NaN, inf or a component outside [-1, 1] raise ConfigError (no silent clip).

    **Observation.** ``Box(OBS_LOW, OBS_HIGH, (16,), float32)`` (clipped into it):
    w_hat / |w0| (3); theta_hat / s (6), with s = trace(inertia_guess)/3 and
    theta = (Jxx, Jxy, Jxz, Jyy, Jyz, Jzz); log10 of the eigenvalues of P_theta / s² in ascending
    order (6); progress = steps taken / budget (1).
    All are scale-free, so a 1 kg·m² CubeSat and a 10⁴ kg·m² stage look alike.

    **Reward.** −cost of the episode. ``cost="info"``: the paper's J = −log(alpha + eps_lambda)
    with alpha the soft-min (eq. 24) over windows of lambda_min of the windowed Gram of
    Psi(w_hat, w_dot_hat). ``cost="posterior"``: the change of log det P_theta over the episode.
    If the estimator diverges the episode ends (terminated) with ``divergence_cost``.

    **Start state.** The scenario's initial attitude and rate; the filter starts at
    ``inertia_guess`` with covariance ``P0_theta`` after a first noisy measurement.

    **Termination.** Only on divergence. **Truncation** once ``budget`` steps (the evaluation
    budget M) are taken; ``TimeLimit`` (``max_episode_steps``, 100 when registered) truncates
    too, whichever comes first.

    **info.** cost, info_cost, posterior_cost, alpha, lambda_min (smallest over windows),
    theta_hat (6,), p_theta_eigvals (6,) ascending, rel_error (||J_hat − J||_F / ||J||_F, the
    simulation knows the truth), xi (3,), duration (s), time (s since reset), diverged; the
    mission limits and what the episode used of them: impulse (N·m·s, sum_i integral |tau_i| dt),
    impulse_demand (what the burst law asked for before the limits cut it),
    impulse_budget (None: unlimited), budget_spent (the budget ran out and cut the bursts),
    rate_peak (the largest true |w|, rad/s), rate_limit (None: unlimited), rate_cuts (bursts
    the rate monitor cut short).

    **Seeding.** ``reset(seed=...)`` seeds ``self.np_random``, which alone draws dwell times,
    measurement times and noise: a seed and an action sequence fix the run.

    **Vectorised.** ``gym.make_vec`` builds the native
    :class:`~inertia_gym.envs.vector.ExcitationVectorEnv` (one call of the batched loop per
    step) unless ``vectorization_mode="sync"`` or ``"async"`` asks for copies of this env.

    Version: v0 (its native vector entry point gives the same results as "sync" mode).
    """

    metadata = {"render_modes": []}

    def __init__(self, scenario: Scenario | Mapping | str | Path | None = None, cost: str = "info",
                 budget: int = 100, carry_over: bool = True):
        """Build the env.

        scenario: the experiment: a Scenario, a mapping of field overrides, or the path of a
        TOML/JSON scenario file (the paper's by default); cost: "info" or "posterior"; budget:
        the evaluation budget M: the progress feature is measured against it and the episode
        is truncated once M steps are taken; carry_over: keep the estimator's state from step
        to step (Algorithm 1).
        """
        self.scenario = as_scenario(scenario)
        self.cost = check_cost(cost)
        self.budget = check_count("budget", budget)
        self.carry_over = bool(carry_over)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self.observation_space = spaces.Box(OBS_LOW, OBS_HIGH, dtype=np.float32)
        self._state: SimState | None = None
        self._steps = 0
        self._time = 0.0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start a new run of Algorithm 1 at the scenario's start; returns (obs, info)."""
        super().reset(seed=check_seed(seed))
        self._state, (info,) = start_runs(self.scenario, [self.np_random])
        self._steps, self._time = 0, 0.0
        return self._observation(), info

    def step(self, action):
        """Run one excitation episode with xi from `action`; returns the Gymnasium 5-tuple."""
        if self._state is None:
            raise ResetNeededError("call reset() before step() (and after a diverged run)")
        step = step_runs(self.scenario, self._state, [action], [self.np_random], cost=self.cost,
                         carry_over=self.carry_over)
        self._state, res, xi, cost = step.state, step.results[0], step.xi[0], step.costs[0]
        self._steps += 1
        self._time += float(res.duration)
        obs = self._observation()
        info = step_info(self.scenario, res, xi, float(cost), self._time)
        if res.diverged:
            self._state = None
        truncated = not res.diverged and self._steps >= self.budget
        return obs, -float(cost), bool(res.diverged), truncated, info

    def _observation(self) -> np.ndarray:
        return observations(self.scenario, self._state, [self._steps], self.budget)[0]
