"""Registers oodmon's envs with gymnasium; ``import oodmon`` runs it once."""

from __future__ import annotations

import gymnasium

__all__ = ["register_envs"]


def register_envs() -> None:
    """Register ``oodmon/CartPole-v1``, ``oodmon/Pendulum-v1`` and ``oodmon/Pong-v5``.

    Idempotent. Episode limits are those of the standard envs: 500 steps for CartPole-v1, 200 for
    Pendulum-v1, and ALE's 108,000 frames for Pong.
    """
    specs = [
        dict(id="oodmon/CartPole-v1", entry_point="oodmon.envs.physics:ShiftedCartPole",
             max_episode_steps=500, reward_threshold=475.0),
        dict(id="oodmon/Pendulum-v1", entry_point="oodmon.envs.physics:ShiftedPendulum",
             max_episode_steps=200),
        dict(id="oodmon/Pong-v5", entry_point="oodmon.envs.pong:CorruptedPong"),
    ]
    for spec in specs:
        if spec["id"] not in gymnasium.registry:
            gymnasium.register(**spec)
