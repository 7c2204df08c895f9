"""Stochastic layers and the switch that samples them at inference.

- :class:`DropConnectLinear` drops weights, not activations (Wan et al., 2013; MC DropConnect,
  Mobiny et al., 2021). Given a batch of K sample rows ``(K, batch, in)`` it draws one weight mask
  per sample row, so K Monte Carlo samples come from one batched computation.
- :func:`mc_sampling` puts only the dropout and DropConnect modules of a network in training mode
  and restores every module's previous mode on exit, also after an exception. (stable-baselines3's
  ``predict()`` switches dropout off, so MC sampling calls the networks directly.)
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch
from torch import nn

from oodmon.errors import InvalidParameterError

__all__ = ["DropConnectLinear", "add_dropout", "is_stochastic", "mc_sampling", "to_dropconnect"]


def _check_p(p: float) -> float:
    if not 0.0 < p < 1.0:
        raise InvalidParameterError(f"drop probability p={p!r} is not allowed; it must satisfy 0 < p < 1")
    return float(p)


class DropConnectLinear(nn.Linear):
    """A linear layer whose weights are dropped with probability ``p`` while in training mode.

    Kept weights are scaled by ``1 / (1 - p)``, so evaluation mode uses the plain weights.
    An input of shape ``(K, batch, in)`` gets K independent weight masks, one per leading row;
    any other shape gets one mask for the whole call.

    Args:
        in_features, out_features, bias: as ``nn.Linear``.
        p: probability of dropping each weight, 0 < p < 1.

    Example:
        >>> layer = DropConnectLinear(3, 2, p=0.5)
        >>> layer(torch.ones(20, 1, 3)).shape
        torch.Size([20, 1, 2])
    """

    def __init__(self, in_features: int, out_features: int, bias: bool = True, *, p: float = 0.1) -> None:
        super().__init__(in_features, out_features, bias=bias)
        self.p = _check_p(p)

    @classmethod
    def from_linear(cls, linear: nn.Linear, p: float) -> DropConnectLinear:
        """A DropConnect layer with ``linear``'s weights (the same parameter tensors)."""
        layer = cls(linear.in_features, linear.out_features, bias=linear.bias is not None, p=p)
        layer.weight, layer.bias = linear.weight, linear.bias
        return layer

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training:
            return super().forward(x)
        keep = 1.0 - self.p
        if x.dim() == 3:
            masks = torch.empty((x.shape[0], *self.weight.shape), device=x.device).bernoulli_(keep)
            weights = masks * (self.weight / keep)
            out = torch.bmm(x, weights.transpose(1, 2))
            return out if self.bias is None else out + self.bias
        mask = torch.empty_like(self.weight).bernoulli_(keep)
        return nn.functional.linear(x, mask * self.weight / keep, self.bias)

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, p={self.p}"


def is_stochastic(module: nn.Module) -> bool:
    """Whether ``module`` is sampled by MC inference: a dropout or DropConnect layer."""
    return isinstance(module, (nn.modules.dropout._DropoutNd, DropConnectLinear))


# Leaf modules whose forward ignores the ``training`` flag. Anything else (dropout, batch norm,
# a user's own layer) may depend on it.
_MODE_FREE_LEAVES: tuple[type[nn.Module], ...] = (
    nn.Linear, nn.Conv1d, nn.Conv2d, nn.Conv3d, nn.ReLU, nn.LeakyReLU, nn.ELU, nn.GELU, nn.SiLU, nn.Tanh,
    nn.Sigmoid, nn.Flatten, nn.Identity, nn.MaxPool2d, nn.AvgPool2d, nn.AdaptiveAvgPool2d,
)


def is_mode_free(network: nn.Module) -> bool:
    """Whether every leaf module of ``network`` computes the same in train and eval mode.

    Such a network needs no mode switching before a deterministic pass (which costs ~0.3 ms a
    call for a Nature CNN at batch one). Containers are not checked; a leaf of a type outside a
    known list counts as mode-dependent unless its class says ``mode_free = True`` (as
    ``networks.ScaleImage`` does): the answer errs on the side of switching.

    Example:
        >>> is_mode_free(nn.Sequential(nn.Linear(2, 8), nn.ReLU())), is_mode_free(nn.Sequential(nn.Dropout()))
        (True, False)
    """
    leaves = [m for m in network.modules() if next(m.children(), None) is None]
    return all(type(m) in _MODE_FREE_LEAVES or getattr(m, "mode_free", False) for m in leaves)


@contextmanager
def mc_sampling(network: nn.Module) -> Iterator[nn.Module]:
    """Sample the network's dropout/DropConnect layers; everything else stays in eval mode.

    Every module's previous ``training`` flag is restored on exit, also after an exception.

    Example:
        >>> net = nn.Sequential(nn.Linear(2, 8), nn.Dropout(0.5), nn.Linear(8, 1)).eval()
        >>> with mc_sampling(net):
        ...     net[1].training, net[0].training
        (True, False)
        >>> net[1].training
        False
    """
    previous = [(module, module.training) for module in network.modules()]
    try:
        for module in network.modules():
            module.training = is_stochastic(module)
        yield network
    finally:
        for module, mode in previous:
            module.training = mode


def add_dropout(mlp: nn.Sequential, p: float, *, last_only: bool = False) -> nn.Sequential:
    """A copy of the layer list of ``mlp`` with ``nn.Dropout(p)`` after hidden activations.

    Args:
        mlp: linear layers and activations, ending with the output layer (and maybe a tanh).
        p: dropout probability, 0 < p < 1.
        last_only: dropout only before the output layer, so that everything before it is
            deterministic and MC sampling computes it once; otherwise after every hidden layer.

    The layers are shared, not copied: training the result trains ``mlp``'s parameters.

    Example:
        >>> add_dropout(nn.Sequential(nn.Linear(4, 8), nn.ReLU(), nn.Linear(8, 2)), 0.1)
        Sequential(
          (0): Linear(in_features=4, out_features=8, bias=True)
          (1): ReLU()
          (2): Dropout(p=0.1, inplace=False)
          (3): Linear(in_features=8, out_features=2, bias=True)
        )
    """
    p = _check_p(p)
    modules = list(mlp)
    linears = [i for i, m in enumerate(modules) if isinstance(m, nn.Linear)]
    first = linears[-2] if last_only and len(linears) > 1 else 0
    layers: list[nn.Module] = []
    for index, module in enumerate(modules):
        layers.append(module)
        if first < index < linears[-1] and not isinstance(module, nn.Linear):
            layers.append(nn.Dropout(p))  # after a hidden layer's activation
    if last_only and len(linears) == 1:  # no hidden layer in the MLP: drop its inputs
        layers.insert(linears[0], nn.Dropout(p))
    return nn.Sequential(*layers)


def to_dropconnect(mlp: nn.Sequential, p: float, *, last_only: bool = False) -> nn.Sequential:
    """A copy of ``mlp`` whose linear layers are :class:`DropConnectLinear` with the same weights.

    Args:
        mlp: the network's layers.
        p: probability of dropping each weight.
        last_only: only the output layer drops weights. Its K weight masks are small
            (K x hidden x outputs), and MC sampling computes the layers before it once.

    Example:
        >>> to_dropconnect(nn.Sequential(nn.Linear(4, 2)), 0.2)
        Sequential(
          (0): DropConnectLinear(in_features=4, out_features=2, bias=True, p=0.2)
        )
    """
    p = _check_p(p)
    linears = [i for i, m in enumerate(mlp) if type(m) is nn.Linear]
    chosen = set(linears[-1:] if last_only else linears)
    return nn.Sequential(
        *(DropConnectLinear.from_linear(m, p) if i in chosen else m for i, m in enumerate(mlp))
    )
