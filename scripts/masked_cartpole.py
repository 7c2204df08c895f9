"""A CartPole whose actions are masked, for sb3-contrib's MaskablePPO: ``--env masked_cartpole:MaskedCartPole-v0``.

Three actions (push left, push right, and push right again) of which the env allows, by its
``action_masks()``, left or the third at even steps and right or the third at odd ones: a policy
that ignored the masks would take forbidden actions. Importing this module registers the id
(gymnasium imports it for ``--env masked_cartpole:MaskedCartPole-v0`` with ``scripts/`` on
``PYTHONPATH``; ``scripts/sb3_contrib_example.py`` does).
"""

from __future__ import annotations

import gymnasium
import numpy as np

ENV_ID = "MaskedCartPole-v0"


class MaskedCartPole(gymnasium.Wrapper):
    """CartPole-v1 with a third action (push right) and masks that alternate with the step."""

    def __init__(self, env: gymnasium.Env | None = None) -> None:
        super().__init__(env if env is not None else gymnasium.make("CartPole-v1"))
        self.action_space = gymnasium.spaces.Discrete(3)
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.t = 0
        return self.env.reset(seed=seed, options=options)

    def step(self, action):
        self.t += 1
        return self.env.step(1 if action == 2 else int(action))

    def action_masks(self) -> np.ndarray:
        return np.array([self.t % 2 == 0, self.t % 2 == 1, True])


if ENV_ID not in gymnasium.registry:
    gymnasium.register(ENV_ID, entry_point=MaskedCartPole)
