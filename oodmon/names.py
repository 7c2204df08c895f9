"""The names every layer shares: the tasks and the uncertainty methods.

A module of its own, importing nothing, so that the command line can offer them as choices
without loading torch or gymnasium. ``oodmon.envs.TASKS`` and ``oodmon.agents.METHODS`` are these.
"""

from __future__ import annotations

__all__ = ["METHODS", "TASKS"]

#: The tasks, each one env of the paper (CartPole, Pendulum: physics shifts; Pong: corrupted frames).
TASKS: tuple[str, ...] = ("cartpole", "pendulum", "pong")

#: The uncertainty methods, for every task.
METHODS: tuple[str, ...] = ("dropout", "dropconnect", "ensemble")
