"""A stable-baselines3 model's own decisions, as :func:`oodmon.agents.sb3.load_sb3` deploys it.

:class:`DeployedModel` is the model's ``predict(obs, deterministic=True)`` on the observation the
monitor reads (unflattened, normalised as in training); :class:`RecurrentDeployedModel` carries a
RecurrentPPO's LSTM state through each episode, :class:`MaskableDeployedModel` gives a MaskablePPO
each step's action masks. :func:`deployed_model` picks the one an algorithm needs.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from oodmon.agents.sb3_decision import decision
from oodmon.agents.vec_normalize import ObservationNormalizer
from oodmon.errors import ConfigError

__all__ = ["DeployedModel", "MaskableDeployedModel", "RecurrentDeployedModel", "deployed_model"]


class DeployedModel:
    """The model's own decision on the observation the monitor reads (a dict one flattened: it
    gets the dict back, as the env gave it; normalised as in training where it was): its
    ``predict(obs, deterministic=True)``, computed without the work ``predict`` repeats at every
    call where :func:`~oodmon.agents.sb3_decision.decision` knows the policy (the same action)."""

    def __init__(self, model: Any, discrete: bool, normalizer: ObservationNormalizer | None,
                 dict_space: gymnasium.spaces.Dict | None = None) -> None:
        self.model, self.discrete, self.normalizer, self.dict_space = model, discrete, normalizer, dict_space
        self.decide = decision(model) or (lambda obs: model.predict(obs, deterministic=True)[0])

    def _as_read(self, obs: np.ndarray) -> Any:
        """``obs`` as the model reads it: a flattened dict unflattened, normalised as in training."""
        if self.dict_space is not None:
            obs = gymnasium.spaces.unflatten(self.dict_space, np.asarray(obs))
        return obs if self.normalizer is None else self.normalizer(obs)

    def _action(self, action: Any) -> int | np.ndarray:
        """The action as the env takes it."""
        return int(action) if self.discrete else np.asarray(action)

    def _predict(self, obs: np.ndarray, **extra: Any) -> tuple[int | np.ndarray, Any]:
        """``model.predict`` of ``obs`` as the model reads it (deterministic; ``extra`` to it): the
        action as the env takes it, and what ``predict`` returned beside it."""
        action, other = self.model.predict(self._as_read(obs), deterministic=True, **extra)
        return self._action(action), other

    def __call__(self, obs: np.ndarray) -> int | np.ndarray:
        return self._action(self.decide(self._as_read(obs)))


class RecurrentDeployedModel(DeployedModel):
    """A recurrent policy's decisions (sb3-contrib's RecurrentPPO): its ``predict`` with the LSTM's
    state carried from step to step, as sb3-contrib's own evaluation carries it, and forgotten when
    an episode begins (:meth:`begin_episode`, which :meth:`Agent.begin_episode` calls: from the envs
    :meth:`Agent.wrap` makes, at each reset, and from the monitor at each episode's start)."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.begin_episode()

    def begin_episode(self) -> None:
        self.state, self.starts = None, np.ones(1, dtype=bool)

    def __call__(self, obs: np.ndarray) -> int | np.ndarray:
        action, self.state = self._predict(obs, state=self.state, episode_start=self.starts)
        self.starts = np.zeros(1, dtype=bool)
        return action


class MaskableDeployedModel(DeployedModel):
    """A policy that decides among the actions the env allows (sb3-contrib's MaskablePPO): its
    ``predict`` with the action masks of the step it acts at, which the envs :meth:`Agent.wrap`
    makes, and the monitor of the env it steps, give it after each reset and step
    (:meth:`Agent.tell_masks`). Each step's masks serve one
    decision: acting again without new ones is an error, never a decision on stale masks."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.masks: np.ndarray | None = None

    def tell_masks(self, masks: np.ndarray) -> None:
        self.masks = masks

    def __call__(self, obs: np.ndarray) -> int | np.ndarray:
        if self.masks is None:
            raise ConfigError("MaskablePPO decides among the actions the env's action masks allow, and none were "
                              f"given for this step: step the env agent.wrap(env) gives, which reads them "
                              f"({_WRAP_FOR_MASKS})")
        masks, self.masks = self.masks, None
        return self._predict(obs, action_masks=masks)[0]


#: Who else gives it the masks: the monitor, of the env it steps.
_WRAP_FOR_MASKS = "the monitor does too: Monitor.run_episode(env), MonitoredEnv(env, monitor), oodmon.watch(..., env=env)"


def deployed_model(model: Any, algorithm: str, discrete: bool, normalizer: ObservationNormalizer | None,
                   dict_space: gymnasium.spaces.Dict | None = None) -> DeployedModel:
    """The decisions of ``model``, an SB3 model of ``algorithm`` (its class's name): a RecurrentPPO's
    with its LSTM's state carried, a MaskablePPO's with the env's action masks, any other's as it is."""
    deploying = {"RecurrentPPO": RecurrentDeployedModel, "MaskablePPO": MaskableDeployedModel}.get(algorithm,
                                                                                                 DeployedModel)
    return deploying(model, discrete, normalizer, dict_space)
