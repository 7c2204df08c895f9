"""Observations stacked as SB3's ``VecFrameStack`` stacks them, for one gymnasium env.

A model trained inside ``VecFrameStack(venv, n_stack)`` (SB3's Atari recipe stacks 4 frames) acts
on the last ``n_stack`` observations side by side: along the last axis (vectors, channels-last
images) or the first (channels-first images), zeros before an episode's first observation; a dict
observation of vectors key by key. A model trained inside ``VecFrameStack(VecNormalize(venv))``
(rl-baselines3-zoo's order: each observation normalised, then stacked) saw normalised zeros before
an episode's first observation: ``pad`` stands the statistics' mean there, which the normaliser
makes zero (:meth:`~oodmon.agents.vec_normalize.ObservationNormalizer.stacked`).
:class:`FrameStack` gives one gymnasium env's observations exactly so, through SB3's own
``StackedObservations``, so that oodmon can fit, calibrate and monitor such a model in the env
(``--frame-stack N``; ``frame_stack=N`` of :func:`~oodmon.agents.sb3.load_sb3`) and a user can
wrap the env they step::

    env = FrameStack(gymnasium.make("CartPole-v1"), 4)   # as VecFrameStack(DummyVecEnv([...]), 4)
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.validation import is_whole

__all__ = ["FrameStack", "Stacking", "check_frame_stack", "restacked"]


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
    ``own_shape``, along the first axis (``channels_first``) or the last. For dict observations,
    which the agent reads flattened (``Agent.view``), ``positions`` are where the newest
    observation's numbers sit in a flattened stack, in the order the env's own dict flattens in
    (``own_shape``: their count). ``pad``: the observation (a vector) that stands before an
    episode's first one instead of zeros (:class:`FrameStack`'s ``pad``).

    Example:
        >>> Stacking(4, (2,), False).newest(np.arange(8.0)).tolist()
        [6.0, 7.0]
    """

    n: int
    own_shape: tuple[int, ...]
    channels_first: bool
    positions: np.ndarray | None = field(default=None, compare=False, repr=False)
    pad: tuple[float, ...] | None = None

    def newest(self, obs: np.ndarray) -> np.ndarray:
        """The env's own newest observation inside a stack: what the detectors read and the logs keep."""
        obs = np.asarray(obs)
        if self.positions is not None:
            return obs[..., self.positions]
        if self.channels_first:
            return obs[-self.own_shape[0]:]
        return obs[..., -self.own_shape[-1]:]


class FrameStack(gymnasium.ObservationWrapper):
    """``env``'s observations stacked ``n_stack`` deep as SB3's ``VecFrameStack`` stacks them
    (``channels_order``: as VecFrameStack's, ``None`` to detect it as it does).

    A dict observation of vectors (a ``Dict`` of ``Box`` spaces) is stacked key by key, as
    VecFrameStack stacks it.

    ``pad``: for vector observations, the observation that stands before an episode's first one
    in the stack instead of zeros (VecFrameStack's), for a model trained inside
    ``VecFrameStack(VecNormalize(venv))``, which saw normalised zeros there: the statistics' mean.

    Raises:
        ConfigError: observations that are neither an array nor a dict of vectors, or a ``pad``
            for other observations than vectors, or of another length.
    """

    def __init__(self, env: gymnasium.Env, n_stack: int, channels_order: str | None = None,
                 pad: Any = None) -> None:
        from stable_baselines3.common.vec_env.stacked_observations import StackedObservations

        super().__init__(env)
        self.n_stack = check_frame_stack(n_stack)
        space = env.observation_space
        self._dict = isinstance(space, gymnasium.spaces.Dict) and all(
            isinstance(sub, gymnasium.spaces.Box) and len(sub.shape) == 1 for sub in space.spaces.values())
        if not isinstance(space, gymnasium.spaces.Box) and not self._dict:
            raise ConfigError(f"oodmon stacks array observations, and dicts of vectors, as VecFrameStack does; this "
                              f"env's are {space}")
        self._stack = StackedObservations(1, self.n_stack, space, channels_order)
        self.observation_space = self._stack.stacked_observation_space
        self._pad, self._filled = None, 0
        if pad is not None:
            if self._dict or len(space.shape) != 1 or np.shape(pad) != space.shape:
                raise ConfigError(f"pad is an observation of a vector env's shape, which stands before an episode's "
                                  f"first; got one of shape {np.shape(pad)} for observations {space}")
            self._pad = np.asarray(pad, space.dtype)
        if self._dict:
            self.stacking = Stacking(self.n_stack, (gymnasium.spaces.flatdim(space),), False, _newest_positions(
                self.observation_space, space))
        else:
            self.stacking = Stacking(self.n_stack, tuple(space.shape), bool(self._stack.channels_first),
                                     pad=None if pad is None else tuple(float(v) for v in self._pad))

    def _one(self, stacked: Any) -> Any:
        """The single env's stack out of StackedObservations' batch of one (a copy)."""
        return {key: value[0].copy() for key, value in stacked.items()} if self._dict else stacked[0].copy()

    def _batch(self, observation: Any) -> Any:
        return ({key: np.asarray(value)[None] for key, value in observation.items()} if self._dict
                else np.asarray(observation)[None])

    def _padded(self, stacked: Any) -> Any:
        """``stacked`` with ``pad`` where VecFrameStack has zeros: before the episode's first observation."""
        missing = self.n_stack - self._filled
        if self._pad is not None and missing > 0:
            stacked[: missing * self._pad.size] = np.tile(self._pad, missing)
        return stacked

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._filled = 1
        return self._padded(self._one(self._stack.reset(self._batch(obs)))), info

    def observation(self, observation: Any) -> Any:
        """The stack with ``observation`` added as the newest (the oldest drops out)."""
        stacked, _ = self._stack.update(self._batch(observation), np.zeros(1, bool), [{}])
        self._filled = min(self._filled + 1, self.n_stack)
        return self._padded(self._one(stacked))


def restacked(observations: Sequence[Any], space: gymnasium.spaces.Space, stacking: Stacking) -> Iterator[Any]:
    """Each step's stack a model trained inside VecFrameStack acted on, rebuilt from
    ``observations``, the env's own (of ``space``: arrays, or dicts of vectors stacked key by key)
    from an episode's reset on, as a log keeps them (:meth:`Stacking.newest`): through
    :class:`FrameStack` itself, so zeros (or ``pad``) before the first, as in the run.

    Example:
        >>> space = gymnasium.spaces.Box(-1, 1, (1,), np.float32)
        >>> own = np.array([[0.5], [0.25], [0.75]], np.float32)
        >>> [stack.tolist() for stack in restacked(own, space, Stacking(2, (1,), False))]
        [[0.0, 0.5], [0.5, 0.25], [0.25, 0.75]]
    """
    stacker = FrameStack(_Replay(observations, space), stacking.n, "first" if stacking.channels_first else "last",
                         stacking.pad)
    yield stacker.reset()[0]
    for _ in range(1, len(observations)):
        yield stacker.step(0)[0]


class _Replay(gymnasium.Env):
    """An env that gives ``observations`` again, one a step from its reset, whatever the action."""

    def __init__(self, observations: Sequence[Any], space: gymnasium.spaces.Space) -> None:
        self.observation_space, self.action_space = space, gymnasium.spaces.Discrete(1)
        self._observations, self._step = observations, 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        self._step = 0
        return self._observations[0], {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self._step += 1
        return self._observations[self._step], 0.0, False, False, {}


def _newest_positions(stacked: gymnasium.spaces.Dict, own: gymnasium.spaces.Dict) -> np.ndarray:
    """Where the newest observation's numbers sit in a flattened stack of dicts of vectors (each
    key's vector stacked along itself, oldest first; the keys in the dict's order, as
    ``gymnasium.spaces.flatten`` puts them), in the order the env's own dict flattens in."""
    positions, start = [], 0
    for key, space in stacked.spaces.items():
        size, own_size = space.shape[0], own.spaces[key].shape[0]
        positions.append(np.arange(start + size - own_size, start + size))
        start += size
    return np.concatenate(positions)
