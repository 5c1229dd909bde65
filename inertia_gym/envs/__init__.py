"""Gymnasium environments; importing this module registers ``InertiaGym/Excitation-v0``."""

from gymnasium.envs.registration import register, registry

from inertia_gym.envs.excitation import ExcitationEnv

ENV_ID = "InertiaGym/Excitation-v0"

if ENV_ID not in registry:
    register(
        id=ENV_ID,
        entry_point="inertia_gym.envs.excitation:ExcitationEnv",
        max_episode_steps=100,
    )

__all__ = ["ENV_ID", "ExcitationEnv"]
