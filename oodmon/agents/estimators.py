"""Uncertainty estimators: the deployed action and the K samples behind it, from one batched pass.

Two kinds of output, one interface:

- ``kind="q_values"`` (DQN): samples are Q-values of shape (K, batch, n_actions); the deployed
  action is the greedy action of the mean Q.
- ``kind="actions"`` (DDPG): samples are actions of shape (K, batch, action_dim), scaled to the
  action space; the deployed action is the mean action.

Two ways to get the K samples:

- :class:`MCEstimator`: Monte Carlo Dropout or DropConnect. The layers before the first
  stochastic one run once; the rest runs once on the activations repeated K times along a new
  leading axis, each row drawing its own masks.
- :class:`EnsembleEstimator`: K members of one architecture, their weights stacked so that one
  batched matrix product per layer computes all members (no Python loop over members).

Both compile the MLP layers they sample to numpy (:mod:`oodmon.agents.plan`): at a batch of one
that is several times faster than torch. Convolutional torsos (Pong) stay in torch.
"""

from __future__ import annotations

import copy
from contextlib import nullcontext
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import torch
from stable_baselines3.common.torch_layers import NatureCNN
from torch import nn
from torch.nn.modules.module import _global_forward_hooks, _global_forward_pre_hooks

from oodmon.agents.layers import DropConnectLinear, is_mode_free, is_stochastic, mc_sampling
from oodmon.agents.plan import Op, StackedAffine, compile_layers, ends_with_tanh, fix_masks, repeat_rows, run
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.names import MASKS, fixed_masks
from oodmon.validation import is_whole

__all__ = ["MASKS", "EnsembleEstimator", "Estimate", "MCEstimator", "UncertaintyEstimator"]

Kind = Literal["q_values", "actions"]


@dataclass(frozen=True)
class Estimate:
    """One decision with the samples behind it.

    Attributes:
        action: the deployed action per observation: (batch,) int64 for DQN, (batch, action_dim)
            float32 for DDPG (in the env's action units). The decision of the samples' mean, but
            for an MC estimator with ``masks="fixed"``: there it is the mean of K freshly sampled
            masks (the paper's MC decision), and the samples are the K fixed sub-networks'.
        samples: (K, batch, n) Q-values (DQN) or actions (DDPG).
        mean: (batch, n) the mean over the K samples.
        std: (batch, n) the standard deviation over the K samples (population, ddof=0).
        pre_squash_std: (batch, n) for an actor ending in tanh, the std of the samples before the
            tanh; ``None`` otherwise. A saturated tanh hides disagreement: members that all push
            hard (pre-tanh 3 and 8) give actions that agree (0.995 and 1.0).
        features: (batch, F) the network's deterministic features: the activations its sampled
            part starts from (MC: the output of the layers before the first stochastic one;
            a shared-torso ensemble: the torso's output, Pong's 512 CNN features; independent
            members: their last hidden layer, averaged over members); ``None`` when the
            estimator cannot tell (a non-sequential MC network).
        pre_squash: (K, batch, n) for an actor ending in tanh, the samples before the tanh (the
            ``scaled_spread`` detector puts each ensemble member's on its own ID footing);
            ``None`` otherwise.
    """

    action: np.ndarray
    samples: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    pre_squash_std: np.ndarray | None = None
    features: np.ndarray | None = field(default=None, repr=False)
    pre_squash: np.ndarray | None = field(default=None, repr=False)


class UncertaintyEstimator:
    """Base of the estimators: observations in, :class:`Estimate` out.

    Subclasses implement :meth:`_sample`, which maps a float32 batch of observations
    (batch, *obs_shape) to samples (K, batch, n) as a numpy array, and may set
    ``self._features`` to the batch's deterministic features on the way (see :class:`Estimate`),
    and ``self._decision`` to other samples of the same shape that the action is decided from.
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
        #: applied to every checked batch before the networks see it: the observation statistics of
        #: an SB3 model trained inside VecNormalize (:mod:`oodmon.agents.vec_normalize`), else None
        self.observation_transform: Callable[[np.ndarray], np.ndarray] | None = None
        self._squash = False  # set by subclasses that apply an actor's final tanh themselves
        if kind == "actions":
            low = np.asarray(action_low, dtype=np.float32)
            high = np.asarray(action_high, dtype=np.float32)
            self._scale, self._offset = (high - low) / 2, (high + low) / 2

    def weights(self) -> dict[str, Any]:
        """What the estimator decides with, names to tensors or arrays (its networks' weights, as
        :func:`oodmon.hashing.state_sha256` hashes them): what tells one estimator's kept fitting
        episodes from another's (:func:`~oodmon.monitor.detectors.fit_detectors`' ``kept``).
        Empty here: each kind of estimator says its own.

        Example:
            >>> from oodmon.agents.layers import add_dropout
            >>> est = MCEstimator(add_dropout(nn.Sequential(nn.Linear(4, 8), nn.ReLU(), nn.Linear(8, 2)), 0.5))
            >>> sorted(est.weights())
            ['0.bias', '0.weight', '3.bias', '3.weight']
        """
        return {}

    def estimate(self, obs: np.ndarray | torch.Tensor) -> Estimate:
        """The deployed action and the K samples for a batch of observations (batch, *obs_shape).

        One observation (of ``obs_shape``, or a 1-D vector when no shape was given) is treated as
        a batch of one.

        Raises:
            InvalidParameterError: observations of another shape than ``obs_shape``.
        """
        batch = np.asarray(obs, dtype=np.float32)
        single_dims = len(self.obs_shape) if self.obs_shape is not None else 1
        if batch.ndim == single_dims:
            batch = batch[None]
        if self.obs_shape is not None and batch.shape[1:] != self.obs_shape:
            raise InvalidParameterError(
                f"observations of shape {batch.shape[1:]} are not allowed; this estimator takes {self.obs_shape} "
                "(one observation) or (batch, *that)"
            )
        if self.observation_transform is not None:
            batch = self.observation_transform(batch)
        self._features = self._decision = None
        samples = self._sample(batch)
        features, self._features = self._features, None
        decision, self._decision = self._decision, None
        pre_squash_std = pre_squash = None
        if self._squash:
            pre_squash, pre_squash_std = samples, _std(samples)
        samples = self._outputs(samples)
        mean = _mean(samples)
        std = _std(samples, mean)
        decided = mean if decision is None else _mean(self._outputs(decision))
        action = decided.argmax(axis=1) if self.kind == "q_values" else decided
        return Estimate(action, samples, mean, std, pre_squash_std, features, pre_squash)

    def _outputs(self, raw: np.ndarray) -> np.ndarray:
        """Samples as the network's outputs give them: squashed by the tanh the compiled layers left
        out (actors), in the env's action units (``kind="actions"``)."""
        samples = np.tanh(raw) if self._squash else raw
        return samples * self._scale + self._offset if self.kind == "actions" else samples

    def _sample(self, batch: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    @property
    def draws(self) -> bool:
        """Whether a decision draws from the estimator's generator (its :attr:`sampling_state`
        moves on): an MC estimator's sampled masks do; an ensemble's members do not, nor fixed
        sub-networks that decide. One that draws nothing plays an episode the same wherever it is
        played (``oodmon.side_by_side``)."""
        return self.sampling_state is not None

    @property
    def sampling_state(self) -> dict | None:
        """Where the estimator's sample generator stands, as plain JSON-able data (``None``: it has
        none). Setting a state saved earlier continues the draws exactly from there: a run that
        stops and resumes samples as one that never stopped.

        Example:
            >>> import torch.nn as nn
            >>> from oodmon.agents.layers import add_dropout
            >>> est = MCEstimator(add_dropout(nn.Sequential(nn.Linear(4, 8), nn.ReLU(), nn.Linear(8, 2)), 0.5), seed=0)
            >>> saved = est.sampling_state
            >>> first = est.estimate(np.ones(4, np.float32)).samples
            >>> est.sampling_state = saved
            >>> bool((est.estimate(np.ones(4, np.float32)).samples == first).all())
            True
        """
        rng = getattr(self, "_rng", None)
        return None if rng is None else rng.bit_generator.state

    @sampling_state.setter
    def sampling_state(self, state: dict) -> None:
        self._rng.bit_generator.state = state


def _mean(samples: np.ndarray) -> np.ndarray:
    """The mean over the samples' first axis: np.mean's sum and division (the same bits: it divides
    in float64 and rounds, which for one division is the float32 division) without its Python
    wrapper, whose cost counts after a CNN has left the caches cold (``benchmarks/pong_step.py``)."""
    return np.add.reduce(samples, 0) / len(samples)


def _std(samples: np.ndarray, mean: np.ndarray | None = None) -> np.ndarray:
    """The std over the samples' first axis: np.std at a third of its overhead."""
    deviation = samples - (_mean(samples) if mean is None else mean)
    return np.sqrt(_mean(deviation * deviation))


class _TorchPart:
    """A deterministic torch part (a CNN torso) as a function of a numpy batch.

    It runs in eval mode for the call, the previous modes restored after; a part whose layers
    ignore the mode (:func:`is_mode_free`, decided once here) is called as it is. Such a part
    with convolutions is copied (like the numpy parts: rebuild the estimator after training) into
    the channels-last memory format, where CPU convolutions of one Atari observation are ~7%
    faster (``benchmarks/pong_step.py``); the outputs are the same up to float rounding.

    A mode-free part whose order of layers is known (:func:`_leaf_chain`) calls its leaf layers'
    ``forward`` one after the other: the same operations as the module's call, without the
    ~3 us of ``nn.Module.__call__`` per layer (a Nature CNN torso has ten: 30-60 us of a
    ~500 us decision).
    """

    def __init__(self, module: nn.Module) -> None:
        self._mode_free = is_mode_free(module)
        self._channels_last = self._mode_free and any(isinstance(m, nn.Conv2d) for m in module.modules())
        self.module = copy.deepcopy(module).to(memory_format=torch.channels_last) if self._channels_last else module
        self._chain = _leaf_chain(self.module) if self._mode_free else None

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(batch)
        if self._channels_last and x.dim() == 4:
            x = x.contiguous(memory_format=torch.channels_last)
        with torch.no_grad(), nullcontext() if self._mode_free else mc_sampling(self.module):
            if self._chain is None or _global_forward_hooks or _global_forward_pre_hooks:
                return self.module(x).numpy()
            for forward in self._chain:
                x = forward(x)
            return x.numpy()


def _leaf_chain(module: nn.Module) -> list[Callable[[torch.Tensor], torch.Tensor]] | None:
    """The ``forward`` methods of ``module``'s leaf layers in the order its call runs them, or
    ``None`` when that order is not known: a container other than ``nn.Sequential`` and SB3's
    ``NatureCNN`` (exactly those classes: a subclass may run its children otherwise), or a hook
    on some module (calling ``forward`` would skip it; global hooks, which may come later, are
    looked for at each call)."""
    if module._forward_hooks or module._forward_pre_hooks:
        return None
    if type(module) is NatureCNN:
        children = [module.cnn, module.linear]  # its forward: self.linear(self.cnn(observations))
    elif type(module) is nn.Sequential:
        children = list(module)
    elif next(module.children(), None) is None:
        return [module.forward]
    else:
        return None
    chain: list[Callable[[torch.Tensor], torch.Tensor]] = []
    for child in children:
        links = _leaf_chain(child)
        if links is None:
            return None
        chain += links
    return chain


class MCEstimator(UncertaintyEstimator):
    """Monte Carlo Dropout or DropConnect over a network with dropout or DropConnect layers.

    For an ``nn.Sequential`` network, the layers before the first stochastic one are
    deterministic: they run once on the batch, and only the rest runs on the K-fold repeated
    activations (K, batch, features). That rest must be linear layers, ReLU/Tanh activations and
    dropout/DropConnect; it is compiled to numpy with the weights it has when the estimator is
    built (build the estimator again after training the network). Layers numpy does not support
    at the start (a CNN) stay in torch.

    Any other network runs in torch on the repeated batch flattened to (K * batch, ...), with only
    its dropout layers in training mode and every module's previous mode restored afterwards. That
    suits dropout (each row draws its own mask) but not DropConnect (one mask per call).

    Args:
        network: maps observations (batch, *obs_shape) to outputs; for ``kind="actions"`` its
            outputs are in [-1, 1] (a tanh head, as SB3's actors).
        n_samples: K, the number of MC samples per decision.
        kind: ``"q_values"`` or ``"actions"``.
        obs_shape: the shape of one observation, to tell one from a batch and check inputs.
        action_low, action_high: the action space's bounds, for ``kind="actions"``.
        seed: seeds the estimator's generator: the same seed gives the same samples. Sampling
            never touches torch's global generator.
        masks: ``"sampled"`` (new masks at every decision) or ``"fixed"``: the K samples come
            from K masks drawn once, from ``mask_seed``, so that sample k drops the same units
            or weights at every decision (common random numbers). Each decision's samples have
            the same distribution as sampled ones, but their spread moves with the state alone,
            not with the draw. The action is still decided by the mean of K freshly sampled
            masks (the deployed policy does not change, at the cost of a second pass): decided
            by the fixed sub-networks themselves, the shifted episodes change too, and how well
            the spread separates them with them (results/bench/README.md, "Fixed masks"). Or
            ``"fixed-decisions"``: the same K fixed sub-networks, which decide too, by their mean
            (one pass, and no random draw after the masks: an implicit ensemble of K sub-networks,
            as Masksembles, Durasov et al. 2021). Fixed masks need an ``nn.Sequential`` network
            (the numpy path).
        mask_seed: seeds the fixed masks (not the sampling ``seed``): the same weights and
            mask seed give the same K sub-networks in every process, which a threshold
            calibrated on them relies on.

    Raises:
        ConfigError: the network has no dropout or DropConnect layer to sample, or layers after
            the first stochastic one other than linear layers, ReLU/Tanh and dropout/DropConnect;
            fixed masks for a network that is not an ``nn.Sequential``.
        InvalidParameterError: ``masks`` not one of :data:`MASKS`.

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
        masks: str = "sampled",
        mask_seed: int = 0,
    ) -> None:
        super().__init__(kind, obs_shape, action_low, action_high)
        if masks not in MASKS:
            raise InvalidParameterError(f"masks={masks!r} is not allowed; use {' or '.join(map(repr, MASKS))}")
        stochastic = [m for m in network.modules() if is_stochastic(m)]
        if not stochastic:
            raise ConfigError(
                f"{type(network).__name__} has no dropout or DropConnect layer, so MC samples would all be "
                "equal; add some (oodmon.agents.layers.add_dropout, to_dropconnect) or use an ensemble"
            )
        if not is_whole(n_samples, 2):
            raise InvalidParameterError(f"n_samples={n_samples!r} is not allowed; it must be an integer >= 2")
        self.network = network
        self.n_samples = n_samples
        self.masks = masks
        self._rng = np.random.default_rng(seed)
        self._torch_prefix: _TorchPart | None = None
        self._prefix: list[Op] | None = None
        self._suffix: list[Op] | None = None
        self._fixed: list[Op] | None = None  # the suffix with its masks drawn once (fixed masks)
        if isinstance(network, nn.Sequential):
            layers = list(network)
            first = next(i for i, m in enumerate(layers) if any(is_stochastic(x) for x in m.modules()))
            self._suffix = compile_layers(layers[first:])
            if self._suffix is None:
                bad = next(m for m in layers[first:] if compile_layers([m]) is None)
                raise ConfigError(
                    f"layers after the first stochastic one must be linear layers, ReLU/Tanh activations and "
                    f"dropout/DropConnect; found {bad!r}"
                )
            # The longest deterministic run before it that numpy supports; torch does the rest.
            start = next(j for j in range(first + 1) if compile_layers(layers[j:first]) is not None)
            self._prefix = compile_layers(layers[start:first])
            self._torch_prefix = _TorchPart(network[:start]) if start > 0 else None
            if kind == "actions" and ends_with_tanh(self._suffix):
                self._suffix, self._squash = self._suffix[:-1], True  # tanh applied in estimate()
            self._fixed = fix_masks(self._suffix, n_samples, np.random.default_rng(mask_seed)) if fixed_masks(masks) else None
        elif fixed_masks(masks):
            raise ConfigError(f"fixed masks need an nn.Sequential network (its layers compiled to numpy); got a "
                              f"{type(network).__name__}")
        elif any(isinstance(m, DropConnectLinear) for m in stochastic):
            raise ConfigError(
                "DropConnect needs an nn.Sequential network (so each sample draws its own weight mask); "
                f"got a {type(network).__name__}"
            )

    def weights(self) -> dict[str, Any]:
        return dict(self.network.state_dict())

    def _sample(self, batch: np.ndarray) -> np.ndarray:
        if self._suffix is None:
            return self._sample_torch(batch)
        hidden = self._torch_prefix(batch) if self._torch_prefix is not None else batch
        hidden = run(self._prefix, hidden, self._rng)
        self._features = hidden.reshape(hidden.shape[0], -1)
        repeated = repeat_rows(hidden, self.n_samples)
        if self.masks == "fixed-decisions":  # the fixed sub-networks decide: one pass
            return run(self._fixed, repeated, self._rng).astype(np.float32, copy=False)
        sampled = run(self._suffix, repeated, self._rng).astype(np.float32, copy=False)
        if self._fixed is None:
            return sampled
        self._decision = sampled
        return run(self._fixed, repeated, self._rng).astype(np.float32, copy=False)

    @property
    def draws(self) -> bool:
        return self.masks != "fixed-decisions"  # fixed sub-networks that decide draw nothing

    def _sample_torch(self, batch: np.ndarray) -> np.ndarray:
        repeated = np.broadcast_to(batch, (self.n_samples, *batch.shape)).reshape(-1, *batch.shape[1:])
        with torch.no_grad(), torch.random.fork_rng(devices=[]), mc_sampling(self.network):
            torch.manual_seed(int(self._rng.integers(2**63)))
            out = self.network(torch.from_numpy(np.ascontiguousarray(repeated)))
        return out.numpy().reshape(self.n_samples, batch.shape[0], -1)


class EnsembleEstimator(UncertaintyEstimator):
    """K members of one MLP architecture, computed together from stacked weights.

    Args:
        members: K ``nn.Sequential`` MLPs of identical architecture (linear layers and
            ReLU/Tanh activations; dropout layers are skipped, as at evaluation).
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
        self.torso = torso if torso is not None else nn.Flatten()
        layers = list(self.torso) if isinstance(self.torso, nn.Sequential) else [self.torso]
        self._torso_ops = compile_layers(layers)  # None: the torso runs in torch (a CNN)
        self._torch_torso = _TorchPart(self.torso) if self._torso_ops is None else None
        layer_lists = [[m for m in member if not is_stochastic(m)] for member in members]
        signature = [_signature(layer) for layer in layer_lists[0]]
        for index, layer_list in enumerate(layer_lists[1:], start=1):
            if [_signature(layer) for layer in layer_list] != signature:
                raise ConfigError(
                    f"ensemble member {index} has another architecture than member 0: "
                    f"{[_signature(l) for l in layer_list]} != {signature}"
                )
        self.n_samples = len(members)
        self._ops: list[Op] = [
            StackedAffine([layer_list[i] for layer_list in layer_lists]) if isinstance(layer, nn.Linear)
            else compile_layers([layer])[0]
            for i, layer in enumerate(layer_lists[0])
        ]
        self._rng = np.random.default_rng(0)  # the ops draw nothing; run() wants a generator
        if kind == "actions" and ends_with_tanh(self._ops):
            self._ops, self._squash = self._ops[:-1], True  # tanh applied in estimate()
        self._head = max(i for i, op in enumerate(self._ops) if isinstance(op, StackedAffine))  # the output layer

    @property
    def draws(self) -> bool:
        return False  # its members decide: nothing drawn

    def weights(self) -> dict[str, Any]:
        # (the members live on as their layers' stacked arrays only)
        stacked = {f"ops.{i}.{name}": getattr(op, name) for i, op in enumerate(self._ops)
                   if isinstance(op, StackedAffine) for name in ("weight_t", "bias")}
        return {f"torso.{name}": value for name, value in self.torso.state_dict().items()} | stacked

    def _sample(self, batch: np.ndarray) -> np.ndarray:
        if self._torso_ops is not None:
            features = run(self._torso_ops, batch, self._rng)
        else:
            features = self._torch_torso(batch)
        hidden = repeat_rows(features, self.n_samples)
        if self._torch_torso is not None:  # a shared torso (Pong): its output
            self._features = features
            return run(self._ops, hidden, self._rng).astype(np.float32, copy=False)
        head = self._head  # independent members: their last hidden layers, averaged
        hidden = run(self._ops[:head], hidden, self._rng)
        self._features = hidden.sum(axis=0) * np.float32(1.0 / self.n_samples)  # np.mean's overhead is 3x
        return run(self._ops[head:], hidden, self._rng).astype(np.float32, copy=False)


def _signature(layer: nn.Module) -> str:
    if isinstance(layer, nn.Linear):
        return f"Linear({layer.in_features},{layer.out_features})"
    if compile_layers([layer]) is None:
        raise ConfigError(
            "ensemble members may hold linear layers and ReLU, Tanh, LeakyReLU, ELU, SiLU, Sigmoid or GELU activations "
            f"only; found {layer!r}"
        )
    return repr(layer)  # with its parameters: LeakyReLU(0.01) is not LeakyReLU(0.2)
