"""Gymnasium environments; importing this module registers ``InertiaGym/Excitation-v0`` and
``InertiaGym/ExcitationBudget-v0``.

``gym.make`` builds the single env (:class:`ExcitationEnv`); ``gym.make_vec`` builds the native
batched :class:`ExcitationVectorEnv` by default (``vectorization_mode="vector_entry_point"``),
or B single envs with ``"sync"`` / ``"async"``.

``InertiaGym/ExcitationBudget-v0`` is the same env on a mission's limits: the shipped
``paper-budget`` scenario (13 N·m·s of impulse per episode, about a third of what the box's
corner spends), the posterior cost, and every step from the scenario's start (a stationary
objective, the one the benchmark's grid reference scores). Any argument can be overridden in
``gym.make`` (for example ``scenario="cubesat-6u-budget"``).
"""

from gymnasium.envs.registration import register, registry

from inertia_gym.envs.excitation import ExcitationEnv
from inertia_gym.envs.vector import ExcitationVectorEnv

ENV_ID = "InertiaGym/Excitation-v0"
BUDGET_ENV_ID = "InertiaGym/ExcitationBudget-v0"
#: The arguments that make ExcitationBudget-v0 of the excitation env.
BUDGET_ENV_KWARGS = {"scenario": "paper-budget", "cost": "posterior", "carry_over": False}

for _id, _kwargs in ((ENV_ID, {}), (BUDGET_ENV_ID, BUDGET_ENV_KWARGS)):
    if _id not in registry:
        register(
            id=_id,
            entry_point="inertia_gym.envs.excitation:ExcitationEnv",
            vector_entry_point="inertia_gym.envs.vector:ExcitationVectorEnv",
            max_episode_steps=100,
            kwargs=dict(_kwargs),
        )

__all__ = ["BUDGET_ENV_ID", "BUDGET_ENV_KWARGS", "ENV_ID", "ExcitationEnv", "ExcitationVectorEnv"]
