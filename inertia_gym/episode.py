"""One excitation episode of Algorithm 1 and its cost, for B runs at once.

An episode applies N bursts of eq. (18) with parameters xi = (a, b, T_on), each followed by a
dwell drawn from the scenario, while truth and estimator run (simulation.py). Its cost is the
paper's J = -log(alpha + eps_lambda), alpha the soft-min (eq. 24) of lambda_min over windows of
N_T = max(5, ceil(T_on/dt)) samples of the Gram of Psi(w_hat, w_dot_hat) (eqs. 12-14). The
estimator state carries over to the next episode (k0 advances), as in Algorithm 1.

Cost options: "info" is the paper's J; "posterior" is the change of log det P_theta over the
episode (the log-volume of the inertia posterior; more negative is more informative), the
posterior-uncertainty cost the paper's conclusion proposes.

Under a scenario's mission limits (impulse_budget, rate_limit) the loop cuts the bursts where a
limit binds, so either cost is the information bought with the impulse allowed: a xi that spends
its budget on the first bursts leaves the later ones, with their fresh directions v, unfired.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.errors import ConfigError
from inertia_gym.excitation import burst_directions, check_xi, episode_schedule
from inertia_gym.information import (
    cost as info_cost,
)
from inertia_gym.information import (
    lambda_min,
    runs_window_grams,
    soft_min,
    window_length,
    window_starts,
)
from inertia_gym.scenario import Scenario
from inertia_gym.simulation import SimState, run_segment
from inertia_gym.validation import relative_error

COSTS = ("info", "posterior")


@dataclasses.dataclass(frozen=True)
class EpisodeResult:
    """Outcome of one episode of one run.

    cost : the selected cost (lower is better).  info_cost : J of eq. (15) with eq. (24).
    posterior_cost : change of log det P_theta over the episode.  alpha : soft-min of lambda_min.
    lambda_min : (W,) lambda_min of each window in S.  duration : s.  v : (3,) burst direction.
    theta_hat : (6,).  p_theta_eigvals : (6,) ascending.  rel_error : ||J_hat - J||_F/||J||_F.
    diverged : the estimator left its domain during the episode (costs are then +inf).
    impulse : N·m·s the bursts spent, sum_i integral |tau_i| dt (at most sc.impulse_budget).
    impulse_demand : N·m·s the burst law asked for before the limits cut it (the design's
    own cost: the bursts fire as designed when it is within the budget).
    rate_peak : the largest true |w| over the episode, rad/s.  budget_spent : the impulse
    budget ran out and cut the bursts.  rate_cuts : bursts the rate monitor cut short.
    """

    cost: float
    info_cost: float
    posterior_cost: float
    alpha: float
    lambda_min: np.ndarray
    duration: float
    v: np.ndarray
    theta_hat: np.ndarray
    p_theta_eigvals: np.ndarray
    rel_error: float
    diverged: bool
    impulse: float
    impulse_demand: float
    rate_peak: float
    budget_spent: bool
    rate_cuts: int


def information_costs(sc: Scenario, w_hat, w_dot_hat, n_steps, bursts, t_on) -> list[tuple]:
    """(J, alpha, lambda_min per window) of each of R episodes' per-step estimates.

    w_hat, w_dot_hat : (R, n, 3) rad/s, rad/s², run r's first n_steps[r] rows. bursts :
    (R, m, 2) [start, stop) step indices. t_on : (R,) s. The window Grams of all runs are
    formed in one compiled call and their eigenvalues in one LAPACK call over the stack.
    """
    n_window = [window_length(t, sc.dt) for t in t_on]
    starts = [window_starts(int(n), nw, b if sc.window_set == "burst" else None)
              for n, nw, b in zip(n_steps, n_window, bursts)]
    offsets = np.r_[0, np.cumsum([len(s) for s in starts])]
    grams = runs_window_grams(w_hat, w_dot_hat, np.concatenate(starts), offsets, n_window,
                              sc.epsilon)
    lam = lambda_min(grams)
    out = []
    for a, b in zip(offsets[:-1], offsets[1:]):
        alpha = soft_min(lam[a:b], sc.softmin_beta)
        out.append((info_cost(alpha, sc.epsilon_lambda), alpha, lam[a:b]))
    return out


def run_episode(sc: Scenario, state: SimState, xi, rngs: list[np.random.Generator], *,
                cost: str = "info") -> tuple[SimState, list[EpisodeResult]]:
    """Run one episode for each of the B runs in `state` with xi (3,) or (B, 3).

    Returns the new state and one EpisodeResult per run. xi is checked against the scenario's
    bounds; each run draws its dwell times, measurement times and noise from its own Generator.
    """
    if cost not in COSTS:
        raise ConfigError(f"cost must be one of {COSTS}, got {cost!r}")
    batch = state.batch
    xi = np.asarray(xi, dtype=float)
    xi = np.tile(xi, (batch, 1)) if xi.ndim == 1 else xi
    if xi.shape != (batch, 3):
        raise ConfigError(f"xi must have shape (3,) or ({batch}, 3), got {xi.shape}")
    for row in xi:
        check_xi(row, sc.xi_bounds)
    schedules = [episode_schedule(sc, row[2], rng) for row, rng in zip(xi, rngs)]
    n_steps = np.array([s.n_steps for s in schedules])
    bursts = np.stack([s.bursts for s in schedules])
    p_theta_start = state.P_theta()
    v = burst_directions(p_theta_start, state.diverged)
    new_state, trace = run_segment(sc, state, n_steps, bursts, xi, v, rngs)
    p_theta_end = new_state.P_theta()
    theta_hat = new_state.theta_hat()
    errors = relative_error(new_state.inertia_hat(), sc.inertia_true_array)
    healthy = np.flatnonzero(~new_state.diverged)
    rows = slice(None) if healthy.size == batch else healthy  # all healthy: the logs, uncopied
    infos = dict(zip(healthy, information_costs(
        sc, trace.w_hat[rows], trace.w_dot_hat[rows], n_steps[rows], bursts[rows],
        xi[rows, 2]))) if healthy.size else {}
    # The runs' 6x6 eigen and determinant problems as stacks (each matrix exactly as alone).
    eig_end = np.full((batch, 6), np.nan)
    post_all = np.full(batch, np.inf)
    if healthy.size:
        eig_end[healthy] = np.linalg.eigvalsh(p_theta_end[healthy])
        post_all[healthy] = (np.linalg.slogdet(p_theta_end[healthy])[1]
                             - np.linalg.slogdet(p_theta_start[healthy])[1])
    results = []
    for r in range(batch):
        diverged = bool(new_state.diverged[r])
        if diverged:
            j_info, alpha, lam, post = np.inf, 0.0, np.zeros(0), np.inf
        else:
            j_info, alpha, lam = infos[r]
            post = float(post_all[r])
        results.append(EpisodeResult(
            cost=j_info if cost == "info" else post, info_cost=j_info, posterior_cost=post,
            alpha=alpha, lambda_min=lam, duration=n_steps[r] * sc.dt, v=v[r],
            theta_hat=theta_hat[r], p_theta_eigvals=eig_end[r], rel_error=float(errors[r]),
            diverged=diverged, impulse=float(trace.impulse[r]),
            impulse_demand=float(trace.demand[r]),
            rate_peak=float(trace.rate_peak[r]), budget_spent=bool(trace.budget_spent[r]),
            rate_cuts=int(trace.rate_cuts[r]),
        ))
    return new_state, results
