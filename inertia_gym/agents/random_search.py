"""Random search: actions drawn uniformly from [-1, 1]^3 (xi uniform inside its bounds)."""

from __future__ import annotations

import numpy as np

from inertia_gym.agents.base import AskTellAgent


class RandomAgent(AskTellAgent):
    """Uniform random search, seeded; ignores the costs it is told."""

    name = "random"

    def __init__(self, seed: int):
        super().__init__(seed)
        self._rng = np.random.default_rng([self.seed, 7])

    def ask(self) -> np.ndarray:
        """Draw uniformly from [-1, 1]^3, shape (3,)."""
        return self._rng.uniform(-1.0, 1.0, size=3)

    def tell(self, action: np.ndarray, cost: float) -> None:
        """Nothing to learn."""
