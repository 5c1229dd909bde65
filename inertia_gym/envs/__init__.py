"""Gymnasium environments; importing this module registers ``InertiaGym/Excitation-v0``.

``gym.make`` builds the single env (:class:`ExcitationEnv`); ``gym.make_vec`` builds the native
batched :class:`ExcitationVectorEnv` by default (``vectorization_mode="vector_entry_point"``),
or B single envs with ``"sync"`` / ``"async"``.
"""

from gymnasium.envs.registration import register, registry

from inertia_gym.envs.excitation import ExcitationEnv
from inertia_gym.envs.vector import ExcitationVectorEnv

ENV_ID = "InertiaGym/Excitation-v0"

if ENV_ID not in registry:
    register(
        id=ENV_ID,
        entry_point="inertia_gym.envs.excitation:ExcitationEnv",
        vector_entry_point="inertia_gym.envs.vector:ExcitationVectorEnv",
        max_episode_steps=100,
    )

__all__ = ["ENV_ID", "ExcitationEnv", "ExcitationVectorEnv"]
