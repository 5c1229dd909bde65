"""Algorithm 1 end to end: run an agent against the excitation env for a budget of M episodes.

`optimize` is what `inertia-gym optimize` and `inertia-gym benchmark` call; `evaluate_xi` scores a
fixed xi fairly (one episode from the scenario's start, averaged over fresh seeds).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.scenario import Scenario

AGENTS = ("bo", "random", "sac", "td3", "ppo")


@dataclasses.dataclass(frozen=True)
class OptimizationResult:
    """One run of Algorithm 1.

    xi_star (3,) (a, b, T_on) with the lowest observed cost (Algorithm 1, line 24); cost_star its
    cost; costs (M,) the cost of each evaluation in order; xis (M, 3) the xi of each evaluation;
    wall_s the wall-clock seconds of the whole run.
    """

    agent: str
    budget: int
    seed: int
    cost_kind: str
    xi_star: np.ndarray
    cost_star: float
    costs: np.ndarray
    xis: np.ndarray
    wall_s: float

    def to_json(self) -> dict:
        """The keys of DESIGN.md section 3 (optimize's result.json), plain JSON types."""
        return {
            "agent": self.agent,
            "budget": int(self.budget),
            "seed": int(self.seed),
            "cost_kind": self.cost_kind,
            "xi_star": [float(x) for x in self.xi_star],
            "cost_star": float(self.cost_star),
            "costs": [float(c) for c in self.costs],
            "xis": np.asarray(self.xis, dtype=float).tolist(),
            "wall_s": float(self.wall_s),
        }


def optimize(agent: str, sc: Scenario, budget: int, seed: int, cost: str = "info",
             progress: bool = False) -> OptimizationResult:
    """Run `agent` for `budget` episodes of the env built on `sc` (Algorithm 1)."""
    raise NotImplementedError("being written (issue 3)")


def evaluate_xi(sc: Scenario, xi, seeds, cost: str = "info") -> float:
    """Mean cost of one episode of xi from the scenario's start over `seeds` (batched)."""
    raise NotImplementedError("being written (issue 3)")
