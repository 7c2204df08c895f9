"""Observations stacked as SB3's ``VecFrameStack`` stacks them, for one gymnasium env.

A model trained inside ``VecFrameStack(venv, n_stack)`` (SB3's Atari recipe stacks 4 frames) acts
on the last ``n_stack`` observations side by side: along the last axis (vectors, channels-last
images) or the first (channels-first images), zeros before an episode's first observation.
:class:`FrameStack` gives one gymnasium env's observations exactly so, through SB3's own
``StackedObservations``, so that oodmon can fit, calibrate and monitor such a model in the env
(``--frame-stack N``; ``frame_stack=N`` of :func:`~oodmon.agents.sb3.load_sb3`) and a user can
wrap the env they step::

    env = FrameStack(gymnasium.make("CartPole-v1"), 4)   # as VecFrameStack(DummyVecEnv([...]), 4)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.validation import is_whole

__all__ = ["FrameStack", "Stacking", "check_frame_stack"]


def check_frame_stack(n_stack: Any, parameter: str = "frame_stack=") -> int:
    """``n_stack`` as an int, or an error naming it as ``parameter`` (a whole number >= 2).

    Example:
        >>> check_frame_stack(4)
        4
    """
    if not is_whole(n_stack, 2):
        raise InvalidParameterError(f"{parameter}{n_stack!r} is not allowed; give the n_stack of the VecFrameStack "
                                    "the model was trained in, a whole number >= 2")
    return int(n_stack)


@dataclass(frozen=True)
class Stacking:
    """How an agent's observations are stacked: ``n`` deep, of the env's own observations of
    ``own_shape``, along the first axis (``channels_first``) or the last.

    Example:
        >>> Stacking(4, (2,), False).newest(np.arange(8.0)).tolist()
        [6.0, 7.0]
    """

    n: int
    own_shape: tuple[int, ...]
    channels_first: bool

    def newest(self, obs: np.ndarray) -> np.ndarray:
        """The env's own newest observation inside a stack: what the detectors read and the logs keep."""
        obs = np.asarray(obs)
        if self.channels_first:
            return obs[-self.own_shape[0]:]
        return obs[..., -self.own_shape[-1]:]


class FrameStack(gymnasium.ObservationWrapper):
    """``env``'s observations stacked ``n_stack`` deep as SB3's ``VecFrameStack`` stacks them
    (``channels_order``: as VecFrameStack's, ``None`` to detect it as it does).

    Raises:
        ConfigError: observations that are not an array (VecFrameStack stacks a dict per key; oodmon
            does not).
    """

    def __init__(self, env: gymnasium.Env, n_stack: int, channels_order: str | None = None) -> None:
        from stable_baselines3.common.vec_env.stacked_observations import StackedObservations

        super().__init__(env)
        self.n_stack = check_frame_stack(n_stack)
        if not isinstance(env.observation_space, gymnasium.spaces.Box):
            raise ConfigError(f"oodmon stacks array observations as VecFrameStack does; this env's are "
                              f"{env.observation_space}")
        self._stack = StackedObservations(1, self.n_stack, env.observation_space, channels_order)
        self.observation_space = self._stack.stacked_observation_space
        self.stacking = Stacking(self.n_stack, tuple(env.observation_space.shape), bool(self._stack.channels_first))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(seed=seed, options=options)
        return self._stack.reset(np.asarray(obs)[None])[0].copy(), info

    def step(self, action: Any) -> tuple[np.ndarray, Any, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self.observation(obs), reward, terminated, truncated, info

    def observation(self, observation: Any) -> np.ndarray:
        """The stack with ``observation`` added as the newest (the oldest drops out)."""
        stacked, _ = self._stack.update(np.asarray(observation)[None], np.zeros(1, bool), [{}])
        return stacked[0].copy()
