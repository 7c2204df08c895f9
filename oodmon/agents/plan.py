"""MLP layers compiled to numpy, for sampling a decision of one (or a few) observations fast.

At a batch of one, a torch call costs more in dispatch than in arithmetic: a [256, 256] MLP
forward is about 30 us in torch and a few us of numpy matrix products. The estimators therefore
copy the weights of the layers they sample into numpy once, when they are built, and draw their
dropout and DropConnect masks from a numpy ``Generator`` (seeded, and never touching torch's
global generator).

Supported layers: ``nn.Linear`` (and :class:`DropConnectLinear`), ``nn.Dropout``, the
activations ``nn.ReLU``, ``nn.Tanh``, ``nn.LeakyReLU``, ``nn.ELU``, ``nn.SiLU``, ``nn.Sigmoid``,
``nn.GELU`` (``activation_fn`` choices of SB3 users), ``nn.Identity`` and a leading ``nn.Flatten``.
:func:`compile_layers` returns ``None`` for anything else, and the caller keeps that part in torch.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence

import numpy as np
from torch import nn

from oodmon.agents.layers import DropConnectLinear

__all__ = ["Op", "Scratch", "StackedAffine", "activation_function", "active_inputs", "bernoulli_positions",
           "compile_layers", "ends_with_tanh", "fix_masks", "repeat_rows", "run"]


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
        bias = linear.bias.detach().numpy() if linear.bias is not None else np.zeros(linear.out_features)
        self.bias = bias.astype(np.float32)

    def __call__(self, x, rng):
        if x.ndim == 3:  # (K, batch, in): one product for all rows, not numpy's loop of K small ones
            rows, batch, _ = x.shape  # (Pong's 20 x 512 -> 6 output layer: 4 us instead of 19)
            return (np.matmul(x.reshape(rows * batch, -1), self.weight_t) + self.bias).reshape(rows, batch, -1)
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


# Below this drop probability a DropConnect layer draws the positions of its dropped weights
# instead of a mask over all of them (see _DropConnect): at p = 0.02 that is 2% of the random
# numbers and no (K, in, out) temporaries; the full-depth Pendulum actor at p = 0.05 decides in
# 1.3 ms instead of 4.2 (benchmarks/uncertainty_step.py). At and above it (the output-layer agents'
# p = 0.1) the dense mask, whose random stream the committed results were made with.
SPARSE_BELOW = 0.1


class _DropConnect(_Affine):
    """Weights dropped with probability p, one mask per leading row of (K, batch, in)."""

    def __init__(self, layer: DropConnectLinear) -> None:
        super().__init__(layer)
        self.p = np.float32(layer.p)
        self.scaled_weight_t = self.weight_t * np.float32(1.0 / (1.0 - layer.p))
        self._scratch = Scratch()  # the sparse path's arrays, kept from call to call

    def __call__(self, x, rng):
        # A weight from an input that is zero everywhere in x contributes nothing whether it is
        # dropped or not: draw masks only for the other inputs. After a ReLU most inputs are zero
        # (84% of a trained Pong agent's 512 features), so this draws a fraction of the random
        # numbers, with the same distribution of outputs.
        weight_t = self.scaled_weight_t
        repeated = x.strides[0] == 0  # K repeats of one batch (the usual case)
        active = active_inputs(x)
        sparse = self.p < SPARSE_BELOW
        if active.size < x.shape[-1]:  # the active inputs' rows of the weights (sparse: into a kept array)
            shape = (active.size, weight_t.shape[1])
            rows = self._scratch("rows", shape[0] * shape[1], np.float32).reshape(shape) if sparse else None
            x, weight_t = x[..., active], np.take(weight_t, active, axis=0, out=rows, mode="clip")
        if sparse:  # the product with every weight kept: once for K repeats of one batch
            full = np.matmul(x[:1] if repeated else x, weight_t)
            return _minus_dropped(full, x, weight_t, float(self.p), rng, self._scratch) + self.bias
        keep = rng.random((x.shape[0], *weight_t.shape), dtype=np.float32) >= self.p
        return np.matmul(x, weight_t * keep) + self.bias


def active_inputs(x: np.ndarray) -> np.ndarray:
    """The indices of the inputs (last axis of x, (K, batch, in)) that are not zero in some row: the
    only ones a DropConnect layer draws masks for. K repeats of one batch (stride 0): one is looked at."""
    rows = x[0] if x.strides[0] == 0 else x
    if rows.ndim == 2 and rows.shape[0] == 1:  # the monitor's one observation: its nonzero inputs, in one call
        return np.flatnonzero(rows)
    return np.flatnonzero((rows != 0).reshape(-1, x.shape[-1]).any(axis=0))


def repeat_rows(x: np.ndarray, k: int) -> np.ndarray:
    """K read-only repeats of ``x`` along a new leading axis, without a copy (stride 0): what
    ``np.broadcast_to(x, (k, *x.shape))`` returns, in a quarter of its time (1 us instead of 4,
    which after a CNN has left the caches cold is ~20 us of a Pong decision)."""
    if not x.flags.c_contiguous:
        return np.broadcast_to(x, (k, *x.shape))
    view = np.ndarray((k, *x.shape), x.dtype, x, 0, (0, *x.strides))
    view.setflags(write=False)
    return view


Buffers = Callable[[str, int, type], np.ndarray]


def _fresh(name: str, size: int, dtype: type) -> np.ndarray:
    """New arrays (:data:`Buffers` that keep nothing): for work done once."""
    return np.empty(size, dtype)


class Scratch:
    """Arrays a compiled layer writes its temporaries into at every call, kept for the next (one
    set per thread): ``scratch(name, size, dtype)`` is the first ``size`` elements of the array
    called ``name``, grown (doubled at least) when too short.

    Why: the sparse DropConnect layers' temporaries (Pendulum's middle layer: eight arrays of
    about 60,000 numbers at every decision) are larger than glibc's malloc serves from its heap
    by default, and it maps fresh pages for them and unmaps them after: about 500 page faults per
    decision, in this VM about 2 us each. ``oodmon run --task pendulum --method dropconnect``
    took 5.1 s for 5 episodes before (640,395 minor faults), 3.6 s with malloc told to keep its
    memory (``MALLOC_MMAP_THRESHOLD_``, 50,975 faults), and 3.3 s with kept arrays, which need no
    such setting (52,644 faults, those of loading; ``benchmarks/page_faults.py``).
    """

    def __init__(self) -> None:
        self._local = threading.local()

    def __reduce__(self):  # copies and pickles start empty (a thread-local cannot be pickled)
        return Scratch, ()

    def __call__(self, name: str, size: int, dtype: type) -> np.ndarray:
        arrays = self._local.__dict__
        array = arrays.get(name)
        if array is None or len(array) < size:
            array = arrays[name] = np.empty(max(size, 0 if array is None else 2 * len(array)), dtype)
        return array[:size]


def _minus_dropped(full: np.ndarray, x: np.ndarray, weight_t: np.ndarray, p: float, rng: np.random.Generator,
                   buffers: Buffers = _fresh) -> np.ndarray:
    """``full`` (the product with every weight kept, (K, batch, out), or (1, batch, out) when x's K
    rows repeat one batch) less the dropped weights' terms, (K, batch, out).

    Each of the K x in x out weights is dropped independently with probability ``p``, as a dense
    mask would drop it: the same distribution of outputs, from about p * K * in * out random numbers.
    ``buffers``: where the temporaries go (a :class:`Scratch`; the result is a new array).
    """
    n_rows, _, n_in = x.shape
    dropped = bernoulli_positions(rng, n_rows * n_in * weight_t.shape[1], p, buffers)
    return _subtract(full, x, *_dropped_terms(dropped, weight_t, buffers), buffers)


def _dropped_terms(dropped: np.ndarray, weight_t: np.ndarray, buffers: Buffers = _fresh
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each dropped weight (position ``(row * in + source) * out + target``) takes its input
    from (``row * in + source``), where its term goes (``row * out + target``), and its value;
    written into ``buffers``' arrays "pair", "slots" and "weights" (and "target", "source")."""
    n_in, n_out = weight_t.shape
    size = len(dropped)
    pair, target, slots = (buffers(name, size, np.int64) for name in ("pair", "target", "slots"))
    if n_out & (n_out - 1) == 0:  # a power of two (the MLPs' 256 and 2 outputs): shifts, not a division
        np.right_shift(dropped, n_out.bit_length() - 1, out=pair)
        np.bitwise_and(dropped, n_out - 1, out=target)
    else:  # a floor division by a scalar (libdivide) and a product: a quarter of np.divmod's time
        np.floor_divide(dropped, n_out, out=pair)
        np.multiply(pair, n_out, out=target)
        np.subtract(dropped, target, out=target)
    row = np.floor_divide(pair, n_in, out=slots)
    source = np.multiply(row, n_in * n_out, out=buffers("source", size, np.int64))
    np.subtract(dropped, source, out=source)  # the position in weight_t
    weights = np.take(weight_t.reshape(-1), source, out=buffers("weights", size, np.float32), mode="clip")
    row *= n_out  # slots = row * n_out + target
    row += target
    return pair, slots, weights


def _subtract(full: np.ndarray, x: np.ndarray, pair: np.ndarray, slots: np.ndarray, weights: np.ndarray,
              buffers: Buffers = _fresh) -> np.ndarray:
    """``full`` (K or 1, batch, out) less the dropped weights' terms (:func:`_dropped_terms`) of x (K, batch, in)."""
    n_rows, batch, n_in = x.shape
    n_out = full.shape[-1]
    if batch == 1:  # the monitor's case: no batch axis to move (the same terms, summed in the same order)
        terms = np.take(x.reshape(n_rows * n_in), pair, out=buffers("terms", len(pair), np.float32), mode="clip")
        # float32 products, widened to the float64 that np.bincount would convert them to (a copy)
        wide = np.multiply(terms, weights, out=buffers("wide", len(pair), np.float64))
        removed = np.bincount(slots, weights=wide, minlength=n_rows * n_out).reshape(n_rows, 1, n_out)
        return full - removed.astype(np.float32)
    inputs = np.moveaxis(x, 1, 0).reshape(batch, n_rows * n_in)  # [b, row * n_in + source]
    slots = slots + (np.arange(batch) * (n_rows * n_out))[:, None]
    removed = np.bincount(slots.ravel(), weights=(inputs[:, pair] * weights).ravel(), minlength=batch * n_rows * n_out)
    return full - np.moveaxis(removed.reshape(batch, n_rows, n_out), 0, 1).astype(np.float32)


def bernoulli_positions(rng: np.random.Generator, size: int, p: float, buffers: Buffers = _fresh) -> np.ndarray:
    """The sorted positions in ``range(size)`` where independent Bernoulli(p) trials succeed (0 < p < 1).

    The gaps between successes are geometric, drawn as ``floor(log(1 - U) / log(1 - p))`` for
    uniform U in [0, 1): ``P(gap >= g) = (1 - p)^g``. Costs O(p * size), not O(size).
    ``buffers``: where the first draw's arrays go ("uniform", "positions"): the positions are then
    a view of one of them, for use before the next call (a rare second draw makes new arrays).

    Example:
        >>> len(bernoulli_positions(np.random.default_rng(0), 100_000, 0.02)) in range(1800, 2200)
        True
    """
    scale = 1.0 / math.log1p(-p)  # < 0 for 0 < p < 1; math's log1p and sqrt: the C library's, as numpy's, sooner
    chunks, end, expected = [], -1, size * p
    while end < size:  # one draw covers ``size`` but for a chance below 1e-9; else draw on from the end
        count = int(expected + 6.0 * math.sqrt(expected) + 16)
        first = not chunks
        uniform = rng.random(out=buffers("uniform", count, np.float64)) if first else rng.random(count)
        np.negative(uniform, out=uniform)
        np.log1p(uniform, out=uniform)
        uniform *= scale
        gaps = buffers("positions", count, np.int64) if first else np.empty(count, np.int64)
        np.copyto(gaps, uniform, casting="unsafe")  # as astype(np.int64): truncation, which is floor here
        gaps += 1
        positions = np.cumsum(gaps, out=gaps)
        positions += end
        chunks.append(positions)
        end = int(positions[-1])
        expected = (size - end) * p
    positions = chunks[0] if len(chunks) == 1 else np.concatenate(chunks)
    return positions[: positions.searchsorted(size)]


# A fixed DropConnect layer keeps its K masked weight matrices whole up to this many numbers
# (1 MiB of float32; a product with them is then one call); larger ones keep only the dropped
# weights, as a sparse matrix subtracted from the product with every weight kept.
DENSE_FIXED_LIMIT = 1 << 18


class _FixedDropConnect(Op):
    """A DropConnect layer whose K weight masks were drawn once: row k of (K, batch, in) drops the
    same weights at every call (sample k is one fixed sub-network).

    The masks are drawn as the sampled layer draws them (the dropped weights' positions below
    ``SPARSE_BELOW``, a dense mask above). Small layers keep the K masked matrices (CartPole's input
    layer, 20 x 4 x 256: with one batch repeated in every row, one product with the K matrices side by
    side); large ones the dropped weights' terms as one block-diagonal ``scipy.sparse`` matrix, whose
    product with the K rows is subtracted from the product with every weight kept (CartPole's middle
    layer, 26,000 of 1.3 million weights at p = 0.02; ``benchmarks/uncertainty_step.py``). Both give
    the masked sums, summed in another order.
    """

    def __init__(self, layer: _DropConnect, k: int, rng: np.random.Generator) -> None:
        from scipy import sparse

        weight_t, self.bias, self.k = layer.scaled_weight_t, layer.bias, k
        n_in, n_out = weight_t.shape
        if layer.p < SPARSE_BELOW:  # the dropped weights' positions, drawn as the sampled layer draws them
            dropped = bernoulli_positions(rng, k * n_in * n_out, float(layer.p))
        else:
            dropped = np.flatnonzero(rng.random((k, n_in, n_out), dtype=np.float32) < layer.p)
        self.weight_t = weight_t
        self.masked = self.side_by_side = self.dropped = None
        if k * n_in * n_out <= DENSE_FIXED_LIMIT:
            masked = np.broadcast_to(weight_t, (k, n_in, n_out)).copy()
            masked.reshape(-1)[dropped] = 0.0
            self.masked = masked
            self.side_by_side = np.ascontiguousarray(masked.transpose(1, 0, 2).reshape(n_in, k * n_out))
        else:  # row k * out + target of the matrix takes column k * in + source, as the sampled layer's terms
            pair, slots, weights = _dropped_terms(dropped, weight_t)
            matrix = sparse.csr_matrix((weights, (slots, pair)), shape=(k * n_out, k * n_in), dtype=np.float32)
            matrix.sort_indices()
            self.dropped = matrix

    def __call__(self, x, rng):
        if x.shape[0] != self.k:
            raise ValueError(f"this layer's masks are fixed for {self.k} rows; got {x.shape[0]}")
        rows, batch, n_in = x.shape
        repeated = x.strides[0] == 0
        if self.masked is not None:
            if repeated:  # one product of the batch with the K matrices side by side
                out = np.matmul(x[0], self.side_by_side).reshape(batch, rows, -1)
                return np.moveaxis(out, 0, 1) + self.bias
            return np.matmul(x, self.masked) + self.bias
        if repeated:
            full = np.matmul(x[:1], self.weight_t)
        else:  # one product of the K * batch rows (numpy would loop over K), with the inputs not zero in some row
            active = active_inputs(x)
            flat = x.reshape(rows * batch, n_in)
            flat, weight_t = (flat, self.weight_t) if active.size == n_in else (flat[:, active], self.weight_t[active])
            full = np.matmul(flat, weight_t).reshape(rows, batch, -1)
        if batch == 1:
            removed = (self.dropped @ x.reshape(rows * n_in)).reshape(rows, 1, -1)
        else:
            stacked = np.moveaxis(x, 1, 2).reshape(rows * n_in, batch)
            removed = np.moveaxis((self.dropped @ stacked).reshape(rows, -1, batch), 2, 1)
        return full - removed + self.bias


class _FixedDropout(Op):
    """Dropout whose K unit masks were drawn once (on the first call, when the width is known, from
    a generator of their own): row k of (K, batch, features) drops the same units at every call."""

    def __init__(self, layer: _Dropout, k: int, rng: np.random.Generator) -> None:
        self.p, self.scale, self.k = layer.p, layer.scale, k
        self._rng = np.random.default_rng(rng.integers(2**63))
        self.keep: np.ndarray | None = None  # (K, 1, features), the scale folded in

    def __call__(self, x, rng):
        if self.keep is None:
            keep = self._rng.random((self.k, 1, x.shape[-1]), dtype=np.float32) >= self.p
            self.keep = keep * self.scale
        return x * self.keep


def fix_masks(ops: Sequence[Op], k: int, rng: np.random.Generator) -> list[Op]:
    """``ops`` with the masks of their dropout and DropConnect layers drawn once from ``rng``, K of
    each: applied to K rows (K, batch, in), row k is the same sub-network at every call. Each mask
    has the sampled layer's distribution; only the draws are shared between calls (common random
    numbers), so the spread over the K rows changes with the input alone, not with the draw.

    Example:
        >>> from oodmon.agents.layers import DropConnectLinear
        >>> ops = fix_masks(compile_layers([DropConnectLinear(3, 2, p=0.5)]), 4, np.random.default_rng(0))
        >>> x = repeat_rows(np.ones((1, 3), np.float32), 4)
        >>> bool((run(ops, x, None) == run(ops, x, None)).all())
        True
    """
    fixed: list[Op] = []
    for op in ops:
        if isinstance(op, _DropConnect):
            fixed.append(_FixedDropConnect(op, k, rng))
        elif isinstance(op, _Dropout):
            fixed.append(_FixedDropout(op, k, rng))
        else:
            fixed.append(op)
    return fixed


class _Function(Op):
    def __init__(self, function) -> None:
        self.function = function

    def __call__(self, x, rng):
        return self.function(x)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return np.float32(0.5) * (np.tanh(np.float32(0.5) * x) + np.float32(1.0))  # no overflow in exp


def activation_function(layer: nn.Module):
    """The numpy function of an activation layer (its parameters included), or ``None``.

    Example:
        >>> activation_function(nn.LeakyReLU(0.1))(np.array([-1.0, 2.0], np.float32)).tolist()
        [-0.10000000149011612, 2.0]
    """
    kind = type(layer)
    if kind is nn.ReLU:
        return lambda x: np.maximum(x, np.float32(0.0))
    if kind is nn.Tanh:
        return np.tanh  # ends_with_tanh tells an actor's squashing output by it
    if kind is nn.Identity:
        return lambda x: x
    if kind is nn.LeakyReLU:
        slope = np.float32(layer.negative_slope)
        return lambda x: np.where(x >= 0, x, x * slope)
    if kind is nn.ELU:
        alpha = np.float32(layer.alpha)
        return lambda x: np.where(x > 0, x, alpha * np.expm1(np.minimum(x, np.float32(0.0))))
    if kind is nn.SiLU:
        return lambda x: x * _sigmoid(x)
    if kind is nn.Sigmoid:
        return _sigmoid
    if kind is nn.GELU and layer.approximate == "none":
        from scipy.special import erf

        return lambda x: np.float32(0.5) * x * (np.float32(1.0) + erf(x * np.float32(1 / math.sqrt(2))))  # float32 in, out
    if kind is nn.GELU and layer.approximate == "tanh":
        scale = np.float32(math.sqrt(2 / math.pi))
        return lambda x: np.float32(0.5) * x * (np.float32(1.0) + np.tanh(scale * (x + np.float32(0.044715) * x ** 3)))
    return None


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
        elif (function := activation_function(layer)) is not None:
            ops.append(_Function(function))
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
