"""MLP layers compiled to numpy, for sampling a decision of one (or a few) observations fast.

At a batch of one, a torch call costs more in dispatch than in arithmetic: a [256, 256] MLP
forward is about 30 us in torch and a few us of numpy matrix products. The estimators therefore
copy the weights of the layers they sample into numpy once, when they are built, and draw their
dropout and DropConnect masks from a numpy ``Generator`` (seeded, and never touching torch's
global generator).

Supported layers: ``nn.Linear`` (and :class:`DropConnectLinear`), ``nn.Dropout``, ``nn.ReLU``,
``nn.Tanh``, ``nn.Identity`` and a leading ``nn.Flatten``. :func:`compile_layers` returns
``None`` for anything else, and the caller keeps that part in torch.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from torch import nn

from oodmon.agents.layers import DropConnectLinear

__all__ = ["Op", "StackedAffine", "compile_layers", "ends_with_tanh", "run"]


class Op:
    """One layer as a numpy function of the activations (..., features) and a generator."""

    def __call__(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        raise NotImplementedError


class _Flatten(Op):
    def __call__(self, x, rng):
        return x.reshape(x.shape[0], -1)


class _Affine(Op):
    def __init__(self, linear: nn.Linear) -> None:
        self.weight_t = linear.weight.detach().numpy().T.astype(np.float32).copy()
        self.bias = (linear.bias.detach().numpy() if linear.bias is not None else np.zeros(linear.out_features)).astype(np.float32)

    def __call__(self, x, rng):
        return np.matmul(x, self.weight_t) + self.bias


class StackedAffine(Op):
    """K linear layers of one shape applied to K rows of activations (K, batch, in)."""

    def __init__(self, linears: Sequence[nn.Linear]) -> None:
        self.weight_t = np.stack([l.weight.detach().numpy().T for l in linears]).astype(np.float32)
        self.bias = np.stack([
            l.bias.detach().numpy() if l.bias is not None else np.zeros(l.out_features) for l in linears
        ]).astype(np.float32)[:, None, :]

    def __call__(self, x, rng):
        return np.matmul(x, self.weight_t) + self.bias


class _Dropout(Op):
    def __init__(self, p: float) -> None:
        self.p, self.scale = np.float32(p), np.float32(1.0 / (1.0 - p))

    def __call__(self, x, rng):
        keep = rng.random(x.shape, dtype=np.float32) >= self.p
        return (x * self.scale) * keep  # multiplying by the bool mask is 10x faster than np.where


class _DropConnect(_Affine):
    """Weights dropped with probability p, one mask per leading row of (K, batch, in)."""

    def __init__(self, layer: DropConnectLinear) -> None:
        super().__init__(layer)
        self.p = np.float32(layer.p)
        self.scaled_weight_t = self.weight_t * np.float32(1.0 / (1.0 - layer.p))

    def __call__(self, x, rng):
        # A weight from an input that is zero everywhere in x contributes nothing whether it is
        # dropped or not: draw masks only for the other inputs. After a ReLU most inputs are zero
        # (84% of a trained Pong agent's 512 features), so this draws a fraction of the random
        # numbers, with the same distribution of outputs.
        weight_t = self.scaled_weight_t
        rows = x[0] if x.strides[0] == 0 else x  # K repeats of one batch (the usual case): look at one
        active = np.flatnonzero((rows != 0).reshape(-1, x.shape[-1]).any(axis=0))
        if active.size < x.shape[-1]:
            x, weight_t = x[..., active], weight_t[active]
        keep = rng.random((x.shape[0], *weight_t.shape), dtype=np.float32) >= self.p
        return np.matmul(x, weight_t * keep) + self.bias


class _Function(Op):
    def __init__(self, function) -> None:
        self.function = function

    def __call__(self, x, rng):
        return self.function(x)


_ACTIVATIONS = {nn.ReLU: lambda x: np.maximum(x, np.float32(0.0)), nn.Tanh: np.tanh, nn.Identity: lambda x: x}


def compile_layers(layers: Sequence[nn.Module]) -> list[Op] | None:
    """The numpy ops of ``layers``, or ``None`` if one of them is not supported.

    The weights are copied: later changes to the modules do not reach the ops.
    """
    ops: list[Op] = []
    for index, layer in enumerate(layers):
        if isinstance(layer, DropConnectLinear):
            ops.append(_DropConnect(layer))
        elif isinstance(layer, nn.Linear):
            ops.append(_Affine(layer))
        elif isinstance(layer, nn.Dropout):
            ops.append(_Dropout(layer.p))
        elif type(layer) in _ACTIVATIONS:
            ops.append(_Function(_ACTIVATIONS[type(layer)]))
        elif isinstance(layer, nn.Flatten) and index == 0 and layer.start_dim == 1:
            ops.append(_Flatten())
        else:
            return None
    return ops


def ends_with_tanh(ops: Sequence[Op]) -> bool:
    """Whether the last op is a tanh (an actor's squashing output)."""
    return bool(ops) and isinstance(ops[-1], _Function) and ops[-1].function is np.tanh


def run(ops: Sequence[Op], x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Apply ``ops`` in order."""
    for op in ops:
        x = op(x, rng)
    return x
