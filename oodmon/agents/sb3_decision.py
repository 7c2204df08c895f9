"""SB3's deterministic ``predict()``, action for action, without the work it repeats at every call.

``model.predict(obs, deterministic=True)`` puts the whole policy in evaluation mode at every call
(``set_training_mode(False)``, a walk that sets every module's flag: a quarter to a third of a small MLP
policy's decision) and, for PPO, A2C and SAC, builds a torch distribution (its arguments
validated) only to read its mode; every call's observation goes through ``obs_to_tensor``'s
dispatch over every kind of space. :func:`decision` gives a function that returns the same action
float for float: it walks the policy into evaluation mode only when one of its modules is in
training mode (a model trained further in memory, say), makes a flat ``Box`` observation a tensor
by that dispatch's own steps for it, and reads the mode from the network's output with the
distribution's own arithmetic. Every other step is ``BasePolicy.predict``'s, in its
order. A policy it does not know keeps ``predict`` (``decision`` returns ``None``): a class that
overrides any method on that path, gSDE, multi-discrete and binary actions read through their own
``_predict``, and sb3-contrib's recurrent and maskable policies, whose ``predict`` takes more
than the observation. ``benchmarks/sb3_decision.py`` measures it against ``predict()``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium
import numpy as np
import torch
import torch.nn.functional as F


def _algorithm_predicts() -> set[Any]:
    """The algorithms' ``predict`` methods that, for ``deterministic=True``, are the policy's own
    (DQN's and QR-DQN's add only epsilon-greedy exploration, for ``deterministic=False``)."""
    from stable_baselines3 import DQN
    from stable_baselines3.common.base_class import BaseAlgorithm

    methods = {BaseAlgorithm.predict, DQN.predict}
    try:
        from sb3_contrib import QRDQN
    except ImportError:
        return methods
    return methods | {QRDQN.predict}


def _keeps(policy: Any, base: type, *names: str) -> bool:
    """Whether ``policy`` is a ``base`` whose methods ``names`` are ``base``'s own."""
    return isinstance(policy, base) and all(getattr(type(policy), name) is getattr(base, name) for name in names)


def _mode(policy: Any) -> Callable[[torch.Tensor], torch.Tensor]:
    """The policy's deterministic action of an observation tensor, as its ``_predict(obs,
    deterministic=True)`` computes it."""
    from stable_baselines3.common.distributions import (
        CategoricalDistribution,
        DiagGaussianDistribution,
        SquashedDiagGaussianDistribution,
    )
    from stable_baselines3.common.policies import ActorCriticPolicy, BaseModel
    from stable_baselines3.sac.policies import Actor, SACPolicy

    if (_keeps(policy, ActorCriticPolicy, "_predict", "get_distribution", "_get_action_dist_from_latent")
            and type(policy.action_dist) in (CategoricalDistribution, DiagGaussianDistribution)):
        categorical = type(policy.action_dist) is CategoricalDistribution

        def actor_critic(obs: torch.Tensor) -> torch.Tensor:  # ActorCriticPolicy.get_distribution, then its mode
            features = BaseModel.extract_features(policy, obs, policy.pi_features_extractor)
            out = policy.action_net(policy.mlp_extractor.forward_actor(features))
            if not categorical:
                return out  # a diagonal Gaussian's mode: its mean
            logits = out - out.logsumexp(dim=-1, keepdim=True)  # torch's Categorical(logits=out)
            return torch.argmax(F.softmax(logits, dim=-1), dim=1)  # its probs; CategoricalDistribution.mode

        return actor_critic
    actor = getattr(policy, "actor", None)
    if (_keeps(policy, SACPolicy, "_predict") and _keeps(actor, Actor, "forward", "get_action_dist_params")
            and type(actor.action_dist) is SquashedDiagGaussianDistribution and not actor.use_sde):
        def sac(obs: torch.Tensor) -> torch.Tensor:
            mean_actions, _, _ = actor.get_action_dist_params(obs)
            return torch.tanh(mean_actions)  # SquashedDiagGaussianDistribution.mode

        return sac
    return lambda obs: policy._predict(obs, deterministic=True)


def _obs_to_tensor(policy: Any) -> Callable[[Any], tuple[Any, bool]]:
    """``policy.obs_to_tensor``, and for a flat ``Box`` observation space (not an image) its own
    steps without the dispatch around them (``np.array``, the shape's check, ``torch.as_tensor``):
    10-15 us of a small policy's 60-100 us decision (``benchmarks/sb3_decision.py``). Any other space, and
    an observation of neither the space's shape nor a batch of it, go through SB3's (its error)."""
    from stable_baselines3.common.policies import BaseModel
    from stable_baselines3.common.preprocessing import is_image_space

    space = policy.observation_space
    if not _keeps(policy, BaseModel, "obs_to_tensor") or type(space) is not gymnasium.spaces.Box or is_image_space(space):
        return policy.obs_to_tensor
    shape, device = space.shape, policy.device

    def box(observation: Any) -> tuple[torch.Tensor, bool]:
        obs = np.array(observation)
        if obs.shape == shape:
            return torch.as_tensor(obs.reshape((1, *shape)), device=device), False
        if obs.shape[1:] == shape:
            return torch.as_tensor(obs, device=device), True
        return policy.obs_to_tensor(observation)  # SB3's own error for the shape

    return box


def decision(model: Any) -> Callable[[Any], np.ndarray] | None:
    """``model.predict(obs, deterministic=True)[0]`` as a function of ``obs``, computed as above,
    or ``None`` for a model whose ``predict`` it does not replace.

    Example:
        >>> from stable_baselines3 import PPO
        >>> model = PPO("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0)
        >>> obs = np.array([0.01, -0.02, 0.03, 0.04], np.float32)
        >>> decision(model)(obs) == model.predict(obs, deterministic=True)[0]
        np.True_
    """
    from stable_baselines3.common.policies import BasePolicy

    policy = model.policy
    if type(model).predict not in _algorithm_predicts() or not _keeps(policy, BasePolicy, "predict"):
        return None
    mode, modules = _mode(policy), list(policy.modules())
    space = policy.action_space
    as_tensor = _obs_to_tensor(policy)

    def decide(obs: Any) -> np.ndarray:  # BasePolicy.predict, step by step
        if any(module.training for module in modules):
            policy.set_training_mode(False)
        obs_tensor, vectorized = as_tensor(obs)
        with torch.no_grad():
            actions = mode(obs_tensor)
        actions = actions.cpu().numpy().reshape((-1, *space.shape))
        if isinstance(space, gymnasium.spaces.Box):
            actions = policy.unscale_action(actions) if policy.squash_output else np.clip(actions, space.low, space.high)
        return actions if vectorized else actions.squeeze(axis=0)

    return decide
