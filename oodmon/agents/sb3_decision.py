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
order. The networks of SB3's own DQN, PPO/A2C, SAC and TD3/DDPG policies are run layer by layer
by each layer's ``forward`` (:func:`_layers`), which is what ``Module.__call__`` calls when no hook
is set: the same torch operations on the same tensors, without ``__call__``'s checks at each of the
eight or so modules a small policy passes through (its decision 7-27% faster); with a
hook set on a module the decision passes through, or a global one, every module is called as
``predict()`` calls it. A policy it does not know keeps ``predict`` (``decision`` returns
``None``): a class that overrides any method on that path, gSDE, multi-discrete and binary
actions read through their own ``_predict``, and sb3-contrib's recurrent and maskable policies,
whose ``predict`` takes more than the observation. ``benchmarks/sb3_decision.py`` measures it against ``predict()``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.modules import module as _torch_module

Layers = Callable[[Any], torch.Tensor]  # what a layer (or layers) does to its input
Mode = Callable[[torch.Tensor], torch.Tensor]  # a policy's deterministic action of an observation tensor

# The hooks Module.__call__ runs for every module (torch.nn.modules.module.register_module_forward_hook
# and its kin fill these dictionaries in place). A torch without one of them: no direct path.
_GLOBAL_HOOKS = tuple(getattr(_torch_module, name, None) for name in (
    "_global_forward_hooks", "_global_forward_pre_hooks", "_global_backward_hooks", "_global_backward_pre_hooks"))
_HOOKS_KNOWN = all(isinstance(hooks, dict) for hooks in _GLOBAL_HOOKS)


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


def _layers(module: nn.Module) -> list[Layers]:
    """What ``module(x)`` computes when no hook is set, as functions to apply in turn: the layers of an
    ``nn.Sequential`` (nested ones too) one by one, a ``FlattenExtractor``'s flattening, and any other
    module's own ``forward`` (whose inner modules it calls as it always does)."""
    from stable_baselines3.common.torch_layers import FlattenExtractor

    kind = type(module)
    if kind is nn.Sequential:
        return [layer for child in module for layer in _layers(child)]
    if kind is FlattenExtractor:
        return _layers(module.flatten)
    return [module.forward]


def _through(model: Any, extractor: nn.Module, *parts: nn.Module | Layers) -> Layers:
    """``BaseModel.extract_features(model, obs, extractor)`` (the observation preprocessed as SB3
    preprocesses it, then the extractor), then each part in turn, by :func:`_layers`: a part that is
    a function rather than a module is called as it is."""
    from stable_baselines3.common.preprocessing import preprocess_obs

    space, normalize = model.observation_space, model.normalize_images
    layers = [layer for part in (extractor, *parts)
              for layer in (_layers(part) if isinstance(part, nn.Module) else [part])]

    def run(obs: Any) -> torch.Tensor:
        x = preprocess_obs(obs, space, normalize_images=normalize)
        for layer in layers:
            x = layer(x)
        return x

    return run


def _called_plainly(modules: list[nn.Module]) -> bool:
    """Whether ``Module.__call__`` would call each of ``modules`` by its ``forward`` alone (no hook of
    its own or global, no compiled call, no tracing): then :func:`_layers` computes what it does."""
    if not _HOOKS_KNOWN or any(_GLOBAL_HOOKS) or torch._C._get_tracing_state():
        return False
    return not any(module._forward_hooks or module._forward_pre_hooks or module._backward_hooks
                   or module._backward_pre_hooks or getattr(module, "_compiled_call_impl", None) is not None
                   for module in modules)


def _mode(policy: Any) -> tuple[Mode, Mode | None, list[nn.Module]]:
    """The policy's deterministic action of an observation tensor, as its ``_predict(obs,
    deterministic=True)`` computes it: through its modules' calls; the same by :func:`_layers`, for
    when no hook is set (``None`` where it does not know the policy's classes); and the modules
    whose hooks that call would run (some more, whose hooks would not: those send it the long way too)."""
    from stable_baselines3.common.distributions import (
        CategoricalDistribution,
        DiagGaussianDistribution,
        SquashedDiagGaussianDistribution,
    )
    from stable_baselines3.common.policies import ActorCriticPolicy, BaseModel
    from stable_baselines3.common.torch_layers import MlpExtractor
    from stable_baselines3.dqn.policies import DQNPolicy, QNetwork
    from stable_baselines3.sac.policies import Actor, SACPolicy
    from stable_baselines3.td3.policies import Actor as TD3Actor
    from stable_baselines3.td3.policies import TD3Policy

    if (_keeps(policy, ActorCriticPolicy, "_predict", "get_distribution", "_get_action_dist_from_latent")
            and type(policy.action_dist) in (CategoricalDistribution, DiagGaussianDistribution)):
        categorical = type(policy.action_dist) is CategoricalDistribution

        def read_mode(out: torch.Tensor) -> torch.Tensor:
            if not categorical:
                return out  # a diagonal Gaussian's mode: its mean
            logits = out - out.logsumexp(dim=-1, keepdim=True)  # torch's Categorical(logits=out)
            return torch.argmax(F.softmax(logits, dim=-1), dim=1)  # its probs; CategoricalDistribution.mode

        def actor_critic(obs: torch.Tensor) -> torch.Tensor:  # ActorCriticPolicy.get_distribution, then its mode
            features = BaseModel.extract_features(policy, obs, policy.pi_features_extractor)
            return read_mode(policy.action_net(policy.mlp_extractor.forward_actor(features)))

        extractor = policy.mlp_extractor
        latent = extractor.policy_net if _keeps(extractor, MlpExtractor, "forward_actor") else extractor.forward_actor
        layers = _through(policy, policy.pi_features_extractor, latent, policy.action_net)
        watched = [*policy.pi_features_extractor.modules(), *extractor.modules(), *policy.action_net.modules()]
        return actor_critic, lambda obs: read_mode(layers(obs)), watched
    actor = getattr(policy, "actor", None)
    if (_keeps(policy, SACPolicy, "_predict") and _keeps(actor, Actor, "forward", "get_action_dist_params")
            and type(actor.action_dist) is SquashedDiagGaussianDistribution and not actor.use_sde):
        def sac(obs: torch.Tensor) -> torch.Tensor:
            mean_actions, _, _ = actor.get_action_dist_params(obs)
            return torch.tanh(mean_actions)  # SquashedDiagGaussianDistribution.mode

        if not _keeps(actor, BaseModel, "extract_features"):
            return sac, None, []
        layers = _through(actor, actor.features_extractor, actor.latent_pi, actor.mu)  # the mean; its log-std unread
        return sac, lambda obs: torch.tanh(layers(obs)), list(actor.modules())

    def own(obs: torch.Tensor) -> torch.Tensor:
        return policy._predict(obs, deterministic=True)

    q_net = getattr(policy, "q_net", None)
    if _keeps(policy, DQNPolicy, "_predict") and _keeps(q_net, QNetwork, "_predict", "forward", "extract_features"):
        layers = _through(q_net, q_net.features_extractor, q_net.q_net)
        return own, lambda obs: layers(obs).argmax(dim=1).reshape(-1), list(q_net.modules())  # QNetwork._predict
    if _keeps(policy, TD3Policy, "_predict") and _keeps(actor, TD3Actor, "forward", "extract_features"):
        return own, _through(actor, actor.features_extractor, actor.mu), list(actor.modules())  # TD3's, DDPG's
    return own, None, []


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
    or ``None`` for a model whose ``predict`` it does not replace. It runs the policy's modules as
    they are when it is made: weights changed in place (further training, ``load_state_dict``) are
    read at each call; a module later replaced by another object is not (make the decision again).

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
    (mode, direct, watched), modules = _mode(policy), list(policy.modules())
    space = policy.action_space
    as_tensor = _obs_to_tensor(policy)

    def decide(obs: Any) -> np.ndarray:  # BasePolicy.predict, step by step
        if any(module.training for module in modules):
            policy.set_training_mode(False)
        obs_tensor, vectorized = as_tensor(obs)
        with torch.no_grad():
            actions = direct(obs_tensor) if direct is not None and _called_plainly(watched) else mode(obs_tensor)
        actions = actions.cpu().numpy().reshape((-1, *space.shape))
        if isinstance(space, gymnasium.spaces.Box):
            actions = policy.unscale_action(actions) if policy.squash_output else np.clip(actions, space.low, space.high)
        return actions if vectorized else actions.squeeze(axis=0)

    return decide
