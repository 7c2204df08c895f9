"""Uncertainty estimators: the deployed action and the K samples behind it, from one batched pass.

Two kinds of output, one interface:

- ``kind="q_values"`` (DQN): samples are Q-values of shape (K, batch, n_actions); the deployed
  action is the greedy action of the mean Q.
- ``kind="actions"`` (DDPG): samples are actions of shape (K, batch, action_dim), scaled to the
  action space; the deployed action is the mean action.

Two ways to get the K samples:

- :class:`MCEstimator`: Monte Carlo Dropout or DropConnect. The batch is repeated K times along a
  new leading axis and goes through the network once with only its stochastic layers sampling.
- :class:`EnsembleEstimator`: K members of one architecture, their weights stacked so that one
  ``torch.baddbmm`` per layer computes all members (no Python loop over members).
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import nn

from oodmon.agents.layers import DropConnectLinear, is_stochastic, mc_sampling
from oodmon.errors import ConfigError, InvalidParameterError

__all__ = ["EnsembleEstimator", "Estimate", "MCEstimator", "UncertaintyEstimator"]

Kind = Literal["q_values", "actions"]


@dataclass(frozen=True)
class Estimate:
    """One decision with the samples behind it.

    Attributes:
        action: the deployed action per observation: (batch,) int64 for DQN, (batch, action_dim)
            float32 for DDPG (in the env's action units).
        samples: (K, batch, n) Q-values (DQN) or actions (DDPG).
        mean: (batch, n) the mean over the K samples.
        std: (batch, n) the standard deviation over the K samples (population, ddof=0).
    """

    action: np.ndarray
    samples: np.ndarray
    mean: np.ndarray
    std: np.ndarray


class UncertaintyEstimator:
    """Base of the estimators: observations in, :class:`Estimate` out.

    Subclasses implement :meth:`_sample`, which maps a float batch of observations
    (batch, *obs_shape) to samples (K, batch, n).
    """

    kind: Kind
    n_samples: int

    def __init__(
        self,
        kind: Kind,
        obs_shape: Sequence[int] | None = None,
        action_low: Sequence[float] | None = None,
        action_high: Sequence[float] | None = None,
    ) -> None:
        if kind not in ("q_values", "actions"):
            raise InvalidParameterError(f"kind={kind!r} is not allowed; use 'q_values' (DQN) or 'actions' (DDPG)")
        if kind == "actions" and (action_low is None or action_high is None):
            raise ConfigError("an 'actions' estimator needs action_low and action_high to scale its tanh outputs")
        self.kind = kind
        self.obs_shape = None if obs_shape is None else tuple(obs_shape)
        if kind == "actions":
            low = torch.as_tensor(action_low, dtype=torch.float32)
            high = torch.as_tensor(action_high, dtype=torch.float32)
            self._scale, self._offset = (high - low) / 2, (high + low) / 2

    def estimate(self, obs: np.ndarray | torch.Tensor) -> Estimate:
        """The deployed action and the K samples for a batch of observations (batch, *obs_shape).

        One observation (of ``obs_shape``, or a 1-D vector when no shape was given) is treated as
        a batch of one.
        """
        batch = torch.as_tensor(np.asarray(obs)).float()
        single_dims = len(self.obs_shape) if self.obs_shape is not None else 1
        if batch.dim() == single_dims:
            batch = batch.unsqueeze(0)
        with torch.no_grad():
            samples = self._sample(batch)
            if self.kind == "actions":
                samples = samples * self._scale + self._offset
            mean = samples.mean(dim=0)
            std = samples.std(dim=0, unbiased=False)
        action = mean.argmax(dim=1) if self.kind == "q_values" else mean
        return Estimate(action.numpy(), samples.numpy(), mean.numpy(), std.numpy())

    def _sample(self, batch: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError


# Modules that act on each row of a (K, batch, features) tensor as on (batch, features).
_ROWWISE = (nn.Linear, nn.ReLU, nn.Tanh, nn.LeakyReLU, nn.ELU, nn.GELU, nn.SiLU, nn.Sigmoid, nn.Identity)


def _rowwise(module: nn.Module) -> bool:
    return isinstance(module, _ROWWISE) or is_stochastic(module)


class MCEstimator(UncertaintyEstimator):
    """Monte Carlo Dropout or DropConnect over a network with dropout or DropConnect layers.

    For an ``nn.Sequential`` network, the layers before the first stochastic one are
    deterministic: they run once on the batch, and only the rest runs on the K-fold repeated
    batch (K, batch, features), which must be linear layers, activations and dropout/DropConnect.
    Any other network runs on the repeated batch flattened to (K * batch, ...), which suits
    dropout layers (each row draws its own mask) but not DropConnect (one mask per call).

    Args:
        network: maps observations (batch, *obs_shape) to outputs; for ``kind="actions"`` its
            outputs are in [-1, 1] (a tanh head, as SB3's actors).
        n_samples: K, the number of MC samples per decision.
        kind: ``"q_values"`` or ``"actions"``.
        obs_shape: the shape of one observation, to tell one from a batch.
        action_low, action_high: the action space's bounds, for ``kind="actions"``.
        seed: with a seed, the estimator draws from its own generator: the same seed gives the
            same samples and torch's global generator is left alone (this costs about 0.1 ms a
            call for saving and restoring torch's state). Without one, masks come from torch's
            global generator.

    Raises:
        ConfigError: the network has no dropout or DropConnect layer to sample, or layers after
            the first stochastic one that cannot run on a (K, batch, features) tensor.

    Example:
        >>> from oodmon.agents.layers import add_dropout
        >>> net = add_dropout(nn.Sequential(nn.Linear(4, 16), nn.ReLU(), nn.Linear(16, 2)), 0.2)
        >>> est = MCEstimator(net, n_samples=20, kind="q_values", seed=0)
        >>> est.estimate(np.zeros(4, np.float32)).samples.shape
        (20, 1, 2)
    """

    def __init__(
        self,
        network: nn.Module,
        n_samples: int = 20,
        kind: Kind = "q_values",
        *,
        obs_shape: Sequence[int] | None = None,
        action_low: Sequence[float] | None = None,
        action_high: Sequence[float] | None = None,
        seed: int | None = None,
    ) -> None:
        super().__init__(kind, obs_shape, action_low, action_high)
        stochastic = [m for m in network.modules() if is_stochastic(m)]
        if not stochastic:
            raise ConfigError(
                f"{type(network).__name__} has no dropout or DropConnect layer, so MC samples would all be "
                "equal; add some (oodmon.agents.layers.add_dropout, to_dropconnect) or use an ensemble"
            )
        if isinstance(n_samples, bool) or not isinstance(n_samples, int) or n_samples < 2:
            raise InvalidParameterError(f"n_samples={n_samples!r} is not allowed; it must be an integer >= 2")
        self.network = network
        self.n_samples = n_samples
        self._rng = None if seed is None else np.random.default_rng(seed)
        self._prefix: nn.Module | None = None
        self._suffix: nn.Module | None = None
        if isinstance(network, nn.Sequential):
            first = next(i for i, m in enumerate(network) if any(is_stochastic(x) for x in m.modules()))
            suffix = list(network)[first:]
            bad = [m for m in suffix if not _rowwise(m)]
            if bad:
                raise ConfigError(
                    f"layers after the first stochastic one must be linear layers, activations and "
                    f"dropout/DropConnect; found {bad[0]!r}"
                )
            self._prefix, self._suffix = network[:first], network[first:]
        elif any(isinstance(m, DropConnectLinear) for m in stochastic):
            raise ConfigError(
                "DropConnect needs an nn.Sequential network (so each sample draws its own weight mask); "
                f"got a {type(network).__name__}"
            )

    def _sample(self, batch: torch.Tensor) -> torch.Tensor:
        isolated = nullcontext() if self._rng is None else torch.random.fork_rng(devices=[])
        with isolated, mc_sampling(self.network):
            if self._rng is not None:
                torch.manual_seed(int(self._rng.integers(2**63)))
            if self._suffix is not None:
                hidden = self._prefix(batch)
                return self._suffix(hidden.unsqueeze(0).expand(self.n_samples, *hidden.shape))
            repeated = batch.unsqueeze(0).expand(self.n_samples, *batch.shape)
            out = self.network(repeated.reshape(-1, *batch.shape[1:]))
            return out.reshape(self.n_samples, batch.shape[0], -1)


class EnsembleEstimator(UncertaintyEstimator):
    """K members of one MLP architecture, computed together from stacked weights.

    Args:
        members: K ``nn.Sequential`` MLPs of identical architecture (linear layers and
            activations; dropout layers are skipped, as at evaluation).
        kind, obs_shape, action_low, action_high: as :class:`MCEstimator`.
        torso: a deterministic network shared by the members, run once on the batch; its
            output (batch, features) feeds every member. The default flattens observations.
            A shared torso with K heads is a bootstrapped ensemble (Osband et al., 2016).

    The weights are copied when the estimator is built: rebuild it after training the members.

    Raises:
        ConfigError: fewer than two members, or members whose architectures differ.

    Example:
        >>> members = [nn.Sequential(nn.Linear(4, 8), nn.ReLU(), nn.Linear(8, 2)) for _ in range(5)]
        >>> EnsembleEstimator(members).estimate(np.zeros((3, 4), np.float32)).samples.shape
        (5, 3, 2)
    """

    def __init__(
        self,
        members: Sequence[nn.Sequential],
        kind: Kind = "q_values",
        *,
        torso: nn.Module | None = None,
        obs_shape: Sequence[int] | None = None,
        action_low: Sequence[float] | None = None,
        action_high: Sequence[float] | None = None,
    ) -> None:
        super().__init__(kind, obs_shape, action_low, action_high)
        if len(members) < 2:
            raise ConfigError(f"an ensemble needs at least 2 members; got {len(members)}")
        self.torso = (torso if torso is not None else nn.Flatten()).eval()
        layer_lists = [[m for m in member if not is_stochastic(m)] for member in members]
        signature = [_signature(layer) for layer in layer_lists[0]]
        for index, layers in enumerate(layer_lists[1:], start=1):
            if [_signature(layer) for layer in layers] != signature:
                raise ConfigError(
                    f"ensemble member {index} has another architecture than member 0: "
                    f"{[_signature(l) for l in layers]} != {signature}"
                )
        self.n_samples = len(members)
        # One entry per layer: stacked (weight^T, bias) for linear layers, the module otherwise.
        self._plan: list[tuple[torch.Tensor, torch.Tensor] | nn.Module] = []
        for position, layer in enumerate(layer_lists[0]):
            if isinstance(layer, nn.Linear):
                linears = [layers[position] for layers in layer_lists]
                weight_t = torch.stack([l.weight.detach().T for l in linears]).contiguous()
                bias = torch.stack([
                    (l.bias.detach() if l.bias is not None else torch.zeros(l.out_features)) for l in linears
                ]).unsqueeze(1)
                self._plan.append((weight_t, bias))
            else:
                self._plan.append(layer)

    def _sample(self, batch: torch.Tensor) -> torch.Tensor:
        features = self.torso(batch)
        hidden = features.unsqueeze(0).expand(self.n_samples, *features.shape)
        for step in self._plan:
            if isinstance(step, tuple):
                hidden = torch.baddbmm(step[1], hidden, step[0])
            else:
                hidden = step(hidden)
        return hidden


def _signature(layer: nn.Module) -> str:
    if isinstance(layer, nn.Linear):
        return f"Linear({layer.in_features},{layer.out_features})"
    if len(list(layer.parameters())):
        raise ConfigError(
            f"ensemble members may hold linear layers and parameter-free activations only; found {layer!r}"
        )
    return type(layer).__name__
