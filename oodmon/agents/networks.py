"""The networks an estimator samples, built from an architecture record or taken from SB3 models.

An architecture is an :class:`Architecture` record, stored in a model's JSON metadata as::

    {"algorithm": "dqn", "obs_shape": [4], "n_outputs": 2, "cnn": false, "net_arch": [256, 256],
     "stochastic": "dropout", "drop_p": 0.1, "last_only": true, "n_members": 1, "shared_torso": false}

``n_outputs`` is the number of actions (DQN) or the action dimension (DDPG, whose head ends in a
tanh). With ``n_members`` = 1 the network is one ``nn.Sequential`` (observations in, outputs out)
sampled by MC; with K > 1 it is a torso (flatten, or Pong's scaling and Nature CNN) and K member
heads. :func:`build_modules` makes the modules from the architecture; :func:`modules_from_sb3`
takes them from trained SB3 models with the same parameter names, so a state dict saved from one
loads into the other.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.torch_layers import CombinedExtractor, NatureCNN, create_mlp
from torch import nn

from oodmon.agents.estimators import EnsembleEstimator, MCEstimator, UncertaintyEstimator
from oodmon.agents.policies import STOCHASTIC_LAYERS
from oodmon.errors import ConfigError, ModelFormatError

__all__ = ["Architecture", "ScaleImage", "build_modules", "estimator_for", "estimator_from_sb3", "modules_from_sb3"]


@dataclass(frozen=True)
class Architecture:
    """What the networks of an agent are: enough to build them again around saved weights.

    Attributes:
        algorithm: ``dqn`` (Q-values out) or ``ddpg`` (actions out, through a tanh).
        obs_shape: the observation's shape.
        n_outputs: the number of actions (DQN) or the action's dimension (DDPG).
        cnn: Pong's scaling and Nature CNN before the heads (else a flatten).
        net_arch: the hidden layers' widths of each head.
        stochastic: ``dropout`` or ``dropconnect`` (MC sampling), or ``None``.
        drop_p, last_only: the stochastic layer's drop probability, and whether it sits at the
            output layer only (see ``layers.add_dropout``).
        n_members: heads of an ensemble (1: one MC-sampled network).
        shared_torso: the heads share one torso (bootstrapped DQN), else each member is whole.

    Example:
        >>> arch = Architecture.of({"algorithm": "dqn", "obs_shape": [4], "n_outputs": 2})
        >>> arch.obs_shape, arch.n_members, Architecture.of(arch.to_json()) == arch
        ((4,), 1, True)
    """

    algorithm: str
    obs_shape: tuple[int, ...]
    n_outputs: int
    cnn: bool = False
    net_arch: tuple[int, ...] = ()
    stochastic: str | None = None
    drop_p: float = 0.0
    last_only: bool = True
    n_members: int = 1
    shared_torso: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "obs_shape", tuple(int(n) for n in self.obs_shape))
        object.__setattr__(self, "net_arch", tuple(int(n) for n in self.net_arch))

    @classmethod
    def of(cls, value: Architecture | Mapping[str, Any]) -> Architecture:
        """``value`` as a record: a record itself, or the dict a model's metadata holds.

        Raises:
            ModelFormatError: a dict with keys an architecture does not have, or without the
                required ``algorithm``, ``obs_shape`` and ``n_outputs``.
        """
        if isinstance(value, cls):
            return value
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(value) - names)
        missing = [n for n in ("algorithm", "obs_shape", "n_outputs") if n not in value]
        if unknown or missing:
            raise ModelFormatError(f"not an architecture record: {'unknown ' + ', '.join(unknown) if unknown else ''}"
                                   f"{'; ' if unknown and missing else ''}{'missing ' + ', '.join(missing) if missing else ''}")
        try:
            arch = cls(**value)
        except (TypeError, ValueError) as error:  # a width or shape that is not a whole number
            raise ModelFormatError(f"not an architecture record ({error})") from None
        if arch.algorithm not in ("dqn", "ddpg"):
            raise ModelFormatError(f"not an architecture record: algorithm {arch.algorithm!r}, not dqn or ddpg")
        if arch.stochastic is not None and arch.stochastic not in STOCHASTIC_LAYERS:
            raise ModelFormatError(f"not an architecture record: stochastic layer {arch.stochastic!r}, not "
                                   f"{' or '.join(STOCHASTIC_LAYERS)}")
        return arch

    def to_json(self) -> dict[str, Any]:
        """The record as a model's metadata stores it (lists, not tuples)."""
        data = asdict(self)
        return data | {"obs_shape": list(self.obs_shape), "net_arch": list(self.net_arch)}


class ScaleImage(nn.Module):
    """uint8 pixel values to [0, 1], as SB3 does before its CNN."""

    mode_free = True  # the same in train and eval mode (see layers.is_mode_free)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x / 255.0


def _torso(arch: Architecture) -> nn.Sequential:
    if arch.cnn:
        space = spaces.Box(0, 255, tuple(arch.obs_shape), dtype=np.uint8)
        return nn.Sequential(ScaleImage(), NatureCNN(space, features_dim=512))
    return nn.Sequential(nn.Flatten())


def _head(arch: Architecture) -> nn.Sequential:
    in_dim = 512 if arch.cnn else math.prod(arch.obs_shape)
    squash = arch.algorithm == "ddpg"
    head = nn.Sequential(*create_mlp(in_dim, arch.n_outputs, list(arch.net_arch), nn.ReLU, squash_output=squash))
    if arch.stochastic:
        head = STOCHASTIC_LAYERS[arch.stochastic](head, arch.drop_p, last_only=arch.last_only)
    return head


def build_modules(arch: Architecture | Mapping[str, Any]) -> nn.Module:
    """Fresh modules of an architecture: ``{"network": ...}`` or ``{"torso": ..., "members": [...]}``.

    Example:
        >>> arch = {"algorithm": "dqn", "obs_shape": [4], "n_outputs": 2, "cnn": False, "net_arch": [8],
        ...         "stochastic": None, "n_members": 3, "shared_torso": False}
        >>> sorted(build_modules(arch).state_dict())[:2]
        ['members.0.0.bias', 'members.0.0.weight']
    """
    arch = Architecture.of(arch)
    if arch.n_members == 1:
        return nn.ModuleDict({"network": nn.Sequential(*_torso(arch), *_head(arch))})
    return nn.ModuleDict({
        "torso": _torso(arch),
        "members": nn.ModuleList(_head(arch) for _ in range(arch.n_members)),
    })


def modules_from_sb3(models: Sequence[Any], arch: Architecture | Mapping[str, Any]) -> nn.Module:
    """The estimation modules of trained SB3 models, shaped as :func:`build_modules` makes them.

    ``models`` holds one model (MC, or bootstrapped heads) or K independently trained members.
    """
    arch = Architecture.of(arch)
    def parts(model) -> tuple[nn.Module, nn.Sequential]:
        if arch.algorithm == "dqn":
            q_net = _q_network(model)
            return q_net.features_extractor, _mean_quantiles(q_net) if hasattr(q_net, "quantile_net") else q_net.q_net
        actor = model.policy.actor
        if _is_sac_actor(actor):  # its deterministic action: tanh of the Gaussian's mean
            return actor.features_extractor, nn.Sequential(*actor.latent_pi, actor.mu, nn.Tanh())
        return actor.features_extractor, actor.mu

    extractor, head = parts(models[0])
    torso = nn.Sequential(ScaleImage(), extractor) if arch.cnn else nn.Sequential(nn.Flatten())
    if arch.n_members == 1:
        return nn.ModuleDict({"network": nn.Sequential(*torso, *head)})
    if arch.shared_torso:
        heads = list(head.heads)
    else:
        heads = [parts(model)[1] for model in models]
    return nn.ModuleDict({"torso": torso, "members": nn.ModuleList(heads)})


def _q_network(model: Any) -> nn.Module:
    """A DQN's Q-network, or a QR-DQN's quantile network (sb3-contrib's)."""
    policy = model.policy
    return policy.q_net if hasattr(policy, "q_net") else policy.quantile_net


def _mean_quantiles(network: nn.Module) -> nn.Sequential:
    """A QR-DQN's quantile network as the Q-network of its Q-values, the mean of each action's
    quantiles (what its ``predict`` takes the argmax of): its last layer's outputs, ``n_quantiles``
    blocks of ``n_actions`` (``view(-1, n_quantiles, n_actions)``), averaged into one block, which
    is the layer of the blocks' mean weights and biases (a mean of linear maps)."""
    *hidden, last = network.quantile_net
    n_quantiles = network.n_quantiles
    mean = nn.Linear(last.in_features, last.out_features // n_quantiles)
    with torch.no_grad():
        mean.weight.copy_(last.weight.view(n_quantiles, -1, last.in_features).mean(dim=0))
        mean.bias.copy_(last.bias.view(n_quantiles, -1).mean(dim=0))
    return nn.Sequential(*hidden, mean)


def _is_sac_actor(actor: nn.Module) -> bool:
    """Whether ``actor`` is SAC's: a Gaussian whose mean (``mu``, after ``latent_pi``) squashed by a
    tanh is its deterministic action, in [-1, 1] as TD3's actor's (both are scaled to the action
    space's bounds by ``predict``). gSDE actors (``use_sde``) are not among them."""
    return isinstance(getattr(actor, "latent_pi", None), nn.Sequential) and isinstance(getattr(actor, "mu", None), nn.Linear) \
        and not getattr(actor, "use_sde", False)


def estimator_for(modules: nn.Module, arch: Architecture | Mapping[str, Any], n_samples: int = 20, seed: int | None = None,
                  action_low: Sequence[float] | None = None, action_high: Sequence[float] | None = None,
                  masks: str = "sampled") -> UncertaintyEstimator:
    """The estimator that samples ``modules`` (from :func:`build_modules` or :func:`modules_from_sb3`);
    ``masks``: an MC estimator's (:class:`~oodmon.agents.estimators.MCEstimator`), ignored by ensembles."""
    arch = Architecture.of(arch)
    kind = "q_values" if arch.algorithm == "dqn" else "actions"
    common = dict(obs_shape=arch.obs_shape, action_low=action_low, action_high=action_high)
    if arch.n_members == 1:
        return MCEstimator(modules["network"].eval(), n_samples, kind, seed=seed, masks=masks, **common)
    return EnsembleEstimator(list(modules["members"]), kind, torso=modules["torso"], **common)


def estimator_from_sb3(models: Sequence[Any], *, n_samples: int = 20, seed: int | None = None,
                       masks: str = "sampled") -> UncertaintyEstimator:
    """An estimator over SB3 models a user trained: an ensemble of several, MC over one.

    Args:
        models: DQN models (or sb3-contrib's QR-DQN models: their quantiles' means), or DDPG/TD3
            models, or SAC models (their deterministic actions; or sb3-contrib's TQC models, whose
            actor is SAC's), all of one architecture. One model must have dropout or DropConnect
            in its Q-network or actor (MC sampling); several form an ensemble with stacked weights.
        n_samples: MC samples per decision (one model only).
        seed: seeds MC sampling.
        masks: one model's MC masks, ``sampled`` or ``fixed`` (see
            :class:`~oodmon.agents.estimators.MCEstimator`); several models are members already.

    Raises:
        ConfigError: no models, mixed algorithms, a single model with nothing to sample, or fixed
            masks for several models.

    Example:
        >>> import gymnasium
        >>> from stable_baselines3 import DQN
        >>> env = gymnasium.make("CartPole-v1")
        >>> members = [DQN("MlpPolicy", env, seed=k) for k in range(3)]
        >>> estimator_from_sb3(members).estimate(np.zeros(4, np.float32)).samples.shape
        (3, 1, 2)
    """
    if not models:
        raise ConfigError("estimator_from_sb3 needs at least one SB3 model")
    kinds = {_kind(m) for m in models}
    if None in kinds or len(kinds) != 1:
        raise ConfigError(
            f"estimator_from_sb3 takes DQN models, DDPG/TD3 models or SAC models, all of one kind; got "
            f"{[type(m).__name__ for m in models]}"
        )
    algorithm = "ddpg" if kinds == {"sac"} else kinds.pop()  # an actor of bounded actions either way
    space = models[0].action_space
    first = _q_network(models[0]) if algorithm == "dqn" else models[0].policy.actor
    arch = Architecture(algorithm, _flat_input_shape(models[0].observation_space, first.features_extractor),
                        int(space.n) if algorithm == "dqn" else int(np.prod(space.shape)),
                        cnn=isinstance(first.features_extractor, NatureCNN), n_members=len(models))
    action_low = space.low.tolist() if algorithm == "ddpg" else None
    action_high = space.high.tolist() if algorithm == "ddpg" else None
    if len(models) > 1 and arch.cnn:
        raise ConfigError("an ensemble of separate CNN models is not supported; use bootstrapped heads (QHeads)")
    if len(models) > 1 and masks != "sampled":
        raise ConfigError(f"masks={masks!r} is for one model with dropout or DropConnect layers; {len(models)} models are "
                          "an ensemble, whose members are fixed already")
    return estimator_for(modules_from_sb3(models, arch), arch, n_samples=n_samples, seed=seed,
                         action_low=action_low, action_high=action_high, masks=masks)


def _kind(model: Any) -> str | None:
    """``dqn`` (DQN, and QR-DQN: its quantiles' means), ``ddpg`` (DDPG and TD3: a deterministic
    actor), ``sac`` (SAC, and TQC: SAC's actor) or ``None`` (another policy)."""
    if hasattr(model.policy, "q_net") or hasattr(model.policy, "quantile_net"):
        return "dqn"
    actor = getattr(model.policy, "actor", None)
    if actor is None:
        return None
    if _is_sac_actor(actor):
        return "sac"
    return "ddpg" if isinstance(getattr(actor, "mu", None), nn.Sequential) else None


def _flat_input_shape(space: Any, extractor: nn.Module) -> tuple[int, ...]:
    """The shape of the observations the estimator reads: the space's own, for discrete values
    (``Discrete``, ``MultiDiscrete``) their one-hot flattening (what SB3's preprocessing gives its
    network, and ``Agent.view`` the estimator), or for a dict of vectors (a ``MultiInputPolicy``)
    the flattened dict, ``gymnasium.spaces.flatten``'s order: the order SB3's ``CombinedExtractor``
    concatenates its keys' flattened vectors in, so its network reads the flattened dict as the
    dict itself.

    Raises:
        ConfigError: a dict read by another feature extractor (images among its keys, a user's own).
    """
    if isinstance(space, (spaces.Discrete, spaces.MultiDiscrete)):
        return (spaces.flatdim(space),)
    if not isinstance(space, spaces.Dict):
        return space.shape
    if not isinstance(extractor, CombinedExtractor) or not all(
            isinstance(e, nn.Flatten) for e in extractor.extractors.values()):
        raise ConfigError(f"the policy reads its dict observations with {type(extractor).__name__}; oodmon samples "
                          "policies whose CombinedExtractor flattens every key (a dict of vectors)")
    return (spaces.flatdim(space),)
