"""Agents that choose xi = (a, b, T_on) for the excitation env: BO (the paper's), random, SB3.

All share :class:`agents.base.Agent`: ``run(env, budget)`` takes exactly ``budget`` env steps.
:func:`make_agent` builds one by name.
"""

from agents.base import Agent, AskTellAgent, make_agent

__all__ = ["Agent", "AskTellAgent", "make_agent"]
