"""``drift``: the dynamics model's residuals, read for a bias rather than for surprise.

The ``dynamics`` detector scores each transition by the model's negative log-likelihood,
averaged over the readings. A change of the physics the policy copes with (a heavier torso, a
weaker motor) can leave each transition no more surprising than ID ones, while the model
misses every one of them the same way: one reading's change comes out a little too small, step
after step. That is a bias of the residuals, which a likelihood averaged over readings dilutes.
This detector standardises each predicted reading's residual by the model's mixture (its
members' variances and their spread; :meth:`DynamicsDetector.standardized_residuals`) and scores a
step by the largest, over readings, of ``|sum of the last window residuals| / sqrt(n)``, which
grows like ``sqrt(n)`` times a bias. On ID transitions the residuals centre on 0 with a spread of
1 at most (a simulator's transitions are exact, and the model's variance floor makes them
smaller: 0.12-0.20 per CartPole reading); the calibration takes the ID scores as they come.

Measured on the logs of the monitor's benchmark (2026-11-29, ``/tmp`` script over the bench's
cached logs and detectors, its threshold the largest of 90 ID episodes' scores from step 20 on,
against the run's own ``combined`` alarm at its calibrated threshold): docs/your-policy.md's PPO hopper,
nine shifts, 89 of 90 shifted episodes alarmed against 62 (a torso of mass 6.5 or 8.0: 10 of 10
each, delay medians about 40 and 26 steps, against 0 and 3 of 10; 0 of 110 further ID episodes);
that page's Acrobot PPO, 65 of 70 against 49 (2 of 110 ID); the shipped CartPole Dropout agent,
290 of 290 against 277; that page's InvertedPendulum PPO, 60 of 70 as ``combined`` (a few steps
slower there). It joins the default set in an env oodmon has no variants of (your own env, where
``combined`` then ranks it beside ``dynamics``); for oodmon's tasks, whose shipped detectors and
results were fitted without it, only when named (``--detectors dynamics,drift,combined``).

Why not in oodmon's tasks' default sets too (measured 2026-11-29, not committed: the monitor's
benchmark, ``--detectors spread,drift,combined`` against ``results/monitor/cartpole.json``): on
CartPole it alarms the same episodes, all failing ones before the failure, with fewer false
alarms (0 / 11 / 1 of 200 against 0 / 16 / 1 for DropConnect / Dropout / ensemble) and shorter
delays at the 90th percentile (4 / 1.1 / 1 against 9 / 2 / 1); on Pendulum ``combined`` with it
raises fewer false alarms than ``dynamics`` (0 / 4 / 0 of 400 against 3 / 4 / 3) but alarms a
step later (delay medians 3 / 2 / 3 against 2 / 2 / 2), so Pendulum's alarm stays on
``dynamics``. But it makes the monitored CartPole step dearer: ``benchmarks/detector_step.py``
(the ensemble's zoo set refitted with it) read 1.57-1.58 against 1.45 without it, above that
benchmark's goal of 1.5, after this detector's own step was brought from 8 to 5 us. The shipped
sets stay without it until the step can pay for it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import InvalidParameterError
from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory
from oodmon.monitor.detectors.dynamics import DynamicsDetector, _FastNll
from oodmon.validation import MOST_STEPS, is_step_count

__all__ = ["DEFAULT_WINDOW", "DriftDetector"]

#: The residuals summed: the dynamics detector's own window.
DEFAULT_WINDOW = 20
#: Entries of the product that sums a step's outputs (:meth:`DriftDetector._buffers`) up to which
#: it is a dense array. It grows with the square of the readings predicted and holds a few
#: nonzeros a column: past some 17 readings (45,000 entries) a sparse one sums faster (measured
#: 2026-11-30, 30 readings: 39 us a step against 78), and 348 readings' dense one was 151 MB and
#: 10.6 ms a step (``benchmarks/drift_step.py``'s wide case).
DENSE_PRODUCT = 50_000


class DriftDetector(Detector):
    """The largest standardised bias of a dynamics model's residuals over the last ``window`` steps.

    Args:
        model: the fitted :class:`~oodmon.monitor.detectors.dynamics.DynamicsDetector` whose
            residuals it reads (its own copy is saved with it).
        window: the residuals summed, at most (fewer just after a reset).

    Example:
        >>> import gymnasium
        >>> from oodmon.monitor.detectors.fitting import collect
        >>> env = gymnasium.make("CartPole-v1")
        >>> episodes = collect(lambda obs: int(obs[2] > 0), env, 6, seed=0)
        >>> drift = DriftDetector.of(DynamicsDetector(2, epochs=5).fit(episodes))
        >>> obs = np.zeros(4, np.float32)
        >>> drift.score(StepContext(obs, 0)), drift.score(StepContext(obs + 1.0, 0, prev_obs=obs, prev_action=0)) > 3
        (0.0, True)
    """

    name = "drift"
    learned = True

    def __init__(self, model: DynamicsDetector | None = None, *, window: int = DEFAULT_WINDOW) -> None:
        if not is_step_count(window):
            raise InvalidParameterError(f"window={window!r} is not allowed; the drift detector sums an integer from 1 to "
                                        f"{MOST_STEPS:,} of last residuals")
        self.model, self.window = model, window
        self._seen = 0  # residuals since the episode began (the window holds the last min(seen, window))
        self._ring: np.ndarray | None = None  # the window's residuals, and their negatives: built on first use
        self._fast: _FastNll | None = None  # the model's forward pass, buffers of its own: built on first use
        self._product: np.ndarray | None = None  # what sums the pass's outputs (with _sums, ...): built on first use

    def __getstate__(self) -> dict[str, Any]:
        # the step's buffers are views of one another (see DynamicsDetector): rebuilt on first use;
        # the window's residuals go with it
        return self.__dict__ | {"_fast": None, "_product": None}

    def read_from(self, dynamics: DynamicsDetector) -> None:
        """Read ``dynamics``' model, if it is this detector's (the same object, or the same settings and
        weights: a set loaded from files holds a copy of each): its forward pass of a step then
        serves both."""
        if self.model is dynamics or self.model is None or not dynamics.fitted:
            return
        if self.model.fingerprint() == dynamics.fingerprint():  # the same settings and arrays
            self.model = dynamics

    @classmethod
    def of(cls, model: DynamicsDetector, *, window: int = DEFAULT_WINDOW) -> DriftDetector:
        """The drift of a fitted dynamics model's residuals."""
        model.check_fitted()
        return cls(model, window=window)

    @property
    def fitted(self) -> bool:
        return self.model is not None and self.model.fitted

    def fit(self, trajectories: Sequence[Trajectory], *, n_actions: int | None = None, seed: int = 0,
            min_logvar: float | None = None) -> DriftDetector:
        """Fit a dynamics model of its own on ``trajectories`` (:meth:`of` reads one fitted already)."""
        extra = {} if min_logvar is None else {"min_logvar": min_logvar}
        self.model = DynamicsDetector(n_actions, seed=seed, **extra).fit(trajectories)
        self._fast = self._product = self._ring = None  # sized for the model before: built anew on first use
        self._seen = 0
        return self

    def reset(self) -> None:
        self._seen = 0
        if self._ring is not None:
            self._ring.fill(0.0)

    def score(self, context: StepContext) -> float:
        """The largest ``|sum of the last residuals| / sqrt(n)`` over readings (an episode's first
        step, and the first after a reading that was not finite: 0, the bias of nothing seen)."""
        self.check_fitted()
        if context.prev_obs is None:
            self.reset()
            return 0.0
        fast = self._pass(context)
        if self._product is None:
            self._buffers(fast)
        self._residuals(fast, out=self._ring[self._seen % self.window])
        self._seen += 1
        total = np.matmul(self._ones, self._ring, out=self._total)  # summed afresh: no running sum to drift
        return float(np.maximum.reduce(total)) / math.sqrt(min(self._seen, self.window))  # each sum, and its negative

    def largest_bias(self) -> tuple[int, float, int] | None:
        """The reading whose residuals summed over the window are the largest in size at the last
        step scored, as (flattened index, the sum over sqrt(n), signed, n: the steps summed): the
        score's own reading (:attr:`~oodmon.monitor.alarms.AlarmEvent.readings` of an alarm it
        raised). ``None`` before a step's residuals (an episode's first step).

        Example:
            >>> import gymnasium
            >>> from oodmon.monitor.detectors.fitting import collect
            >>> episodes = collect(lambda obs: int(obs[2] > 0), gymnasium.make("CartPole-v1"), 6, seed=0)
            >>> drift = DriftDetector.of(DynamicsDetector(2, epochs=5).fit(episodes))
            >>> obs = np.zeros(4, np.float32)
            >>> drift.score(StepContext(obs, 0)), drift.largest_bias()
            (0.0, None)
            >>> before = obs - np.array([0, 0, 0, 1], np.float32)  # the pole turning 1 faster
            >>> score = drift.score(StepContext(obs, 0, prev_obs=before, prev_action=0))
            >>> index, bias, steps = drift.largest_bias()
            >>> index, abs(bias) == score, steps
            (3, True, 1)
        """
        total = getattr(self, "_total", None)
        if self._seen == 0 or total is None:
            return None
        readings = len(total) // 2  # each reading's sum, then its negative
        k = int(np.argmax(total))
        j, sign = (k, 1.0) if k < readings else (k - readings, -1.0)
        predicted, steps = self.model.predicted, min(self._seen, self.window)
        return int(j if predicted is None else predicted[j]), sign * float(total[k]) / math.sqrt(steps), steps

    def _pass(self, context: StepContext) -> _FastNll:
        """The model's fast forward pass of the step's transition (:class:`_FastNll`, equal to the
        batch path up to float32 rounding; ``benchmarks/drift_step.py`` times it): the pass the
        dynamics detector just made of this very step where it did (the set's detector, on the same
        weights: :meth:`read_from`), else one of its own."""
        model = self.model
        if model.scored is context and model._fast is not None:
            return model._fast
        fast = self._fast
        if fast is None:
            fast = self._fast = _FastNll(model)
        prev_obs, obs = context.prev_obs, context.obs
        if model.flatten:
            prev_obs, obs = np.ravel(prev_obs), np.ravel(obs)
        fast(prev_obs, context.prev_action, obs)
        return fast

    def _buffers(self, fast: _FastNll) -> None:
        """The arrays of a step, allocated once (a view made per call costs as much as a small
        ufunc), and the product that sums the pass's outputs (see :meth:`_residuals`)."""
        members, d = fast.members, fast.d
        at = fast.outputs_layout()
        size = len(fast.outputs)
        square = size + at["mean"]  # the outputs' squares follow them in the float64 copy
        rows, columns, values = [], [], []  # of the product; its columns: a, -a, then twice each of the others

        def put(row: np.ndarray | int, column: int, value: float) -> None:
            row = np.atleast_1d(row)
            rows.append(row)
            columns.append(np.full(len(row), column))
            values.append(np.full(len(row), value))

        for j in range(d):
            for sign, column in ((1.0, j), (-1.0, d + j)):
                put(at["mean"][:, j], column, sign)  # a: the means summed, less M times the change
                put(at["change"][j], column, -sign * members)
            for column in (2 * d + j, 3 * d + j):
                put(square[:, j], column, members)  # M b: the squares and the w summed, times M
                put(at["w"][:, j], column, members)
            for column in (4 * d + j, 5 * d + j):
                put(at["mean"][:, j], column, 1.0)  # the means summed
        shape = (size + fast.out.size, 6 * d)
        rows, columns, values = np.concatenate(rows), np.concatenate(columns), np.concatenate(values)
        if shape[0] * shape[1] <= DENSE_PRODUCT:
            product = np.zeros(shape)
            product[rows, columns] = values
        else:  # a long observation's: a few nonzeros a column (of d^2 entries), summed sparse, transposed
            from scipy.sparse import csr_array

            product = csr_array((values, (columns, rows)), shape=shape[::-1])
        self._product = product
        self._outputs = np.empty(shape[0])  # float64 (see _residuals): the pass's outputs, then their squares
        self._copied, self._out, self._squares = (self._outputs[:size], self._outputs[:fast.out.size],
                                                  self._outputs[size:])
        self._sums = np.empty(6 * d)
        self._bias, self._twice, self._mean_sum = self._sums[:2 * d], self._sums[2 * d:4 * d], self._sums[4 * d:]
        self._variance = np.empty(2 * d)
        if self._ring is None:
            self._ring = np.zeros((self.window, 2 * d))  # each step's residuals, and their negatives
        self._ones = np.ones(self.window)
        self._total = np.empty(2 * d)

    def _residuals(self, fast: _FastNll, out: np.ndarray) -> np.ndarray:
        """The step's standardised residuals and their negatives (the score reads magnitudes: the
        larger of a sum and its negative), into ``out``: :meth:`DynamicsDetector.standardized_residuals`
        (turned) from the pass's buffers, in few numpy calls. The pass leaves each member's mean
        ``m_k``, its variance over the floor ``w_k`` and the change ``y``, in units of ``exp(min_logvar
        / 2)`` (the residual, a ratio, is the same in them). Over ``M`` members the mixture's mean
        ``sum m_k / M`` is off the change by ``a / M``, ``a = sum m_k - M y``, and its variance (the
        members' and their spread) is ``(M sum (m_k^2 + w_k) - (sum m_k)^2) / M^2``: the residual
        (turned) is ``a / sqrt(M sum (m_k^2 + w_k) - (sum m_k)^2)``. The sums are one product of the
        pass's outputs (``_FastNll.outputs``) and their squares, in float64: the difference is at least
        ``M^2`` (every ``w_k >= 1``), the rounding some 1e-16 of the sums (in float32, squares of
        large changes on which the members agree would round by more than the variance)."""
        self._copied[...] = fast.outputs
        np.multiply(self._out, self._out, out=self._squares)
        if isinstance(self._product, np.ndarray):
            np.matmul(self._outputs, self._product, out=self._sums)
        else:
            self._sums[...] = self._product @ self._outputs
        variance = np.multiply(self._mean_sum, self._mean_sum, out=self._variance)
        np.subtract(self._twice, variance, out=variance)
        np.sqrt(variance, out=variance)
        return np.divide(self._bias, variance, out=out)

    # -- state -------------------------------------------------------------------------------------
    def config(self) -> dict[str, Any]:
        self.check_fitted()
        return {"window": self.window, "model": self.model.config()}

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {f"model.{key}": value for key, value in self.model.tensors().items()}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> DriftDetector:
        model = DynamicsDetector.from_state(config["model"], {k[6:]: v for k, v in tensors.items()
                                                              if k.startswith("model.")})
        return cls(model, window=config.get("window", DEFAULT_WINDOW))
