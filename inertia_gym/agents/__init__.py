"""Agents that choose xi = (a, b, T_on) for the excitation env: BO (the paper's), random, SB3.

All share :class:`inertia_gym.agents.base.Agent`: ``run(env, budget)`` takes exactly ``budget``
env steps.
:func:`make_agent` builds one by name from the registry :data:`AGENTS`.
"""

from inertia_gym.agents.base import AGENTS, Agent, AskTellAgent, make_agent

__all__ = ["AGENTS", "Agent", "AskTellAgent", "make_agent"]
