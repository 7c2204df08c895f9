"""The names every layer shares: the tasks, the uncertainty methods and the MC masks.

A module of its own, importing nothing, so that the command line can offer them as choices
without loading torch or gymnasium. ``oodmon.envs.TASKS`` and ``oodmon.agents.METHODS`` are these.
"""

from __future__ import annotations

__all__ = ["MASKS", "METHODS", "TASKS"]

#: The tasks, each one env of the paper (CartPole, Pendulum: physics shifts; Pong: corrupted frames).
TASKS: tuple[str, ...] = ("cartpole", "pendulum", "pong")

#: The uncertainty methods, for every task.
METHODS: tuple[str, ...] = ("dropout", "dropconnect", "ensemble")

#: How an MC estimator draws its masks: ``sampled`` anew at every decision (MC Dropout and
#: DropConnect as the paper samples them), or ``fixed``: K masks drawn once, so that sample k is the
#: same sub-network at every decision (see ``oodmon.agents.estimators.MCEstimator``).
MASKS: tuple[str, ...] = ("sampled", "fixed")
