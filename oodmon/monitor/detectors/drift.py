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
against the run's own ``combined`` alarm at its calibrated threshold): the README's PPO hopper,
nine shifts, 89 of 90 shifted episodes alarmed against 62 (a torso of mass 6.5 or 8.0: 10 of 10
each, delay medians about 40 and 26 steps, against 0 and 3 of 10; 0 of 110 further ID episodes);
the README's Acrobot PPO, 65 of 70 against 49 (2 of 110 ID); the shipped CartPole Dropout agent,
290 of 290 against 277; the README's InvertedPendulum PPO, 60 of 70 as ``combined`` (a few steps
slower there). It joins the default set in an env oodmon has no variants of (your own env, where
``combined`` then ranks it beside ``dynamics``); for oodmon's tasks, whose shipped detectors and
results were fitted without it, only when named (``--detectors dynamics,drift,combined``).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import InvalidParameterError
from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory
from oodmon.monitor.detectors.dynamics import DynamicsDetector, _FastNll
from oodmon.validation import is_whole

__all__ = ["DEFAULT_WINDOW", "DriftDetector"]

#: The residuals summed: the dynamics detector's own window.
DEFAULT_WINDOW = 20


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
        if not is_whole(window):
            raise InvalidParameterError(f"window={window!r} is not allowed; the drift detector sums an integer >= 1 of "
                                        "last residuals")
        self.model, self.window = model, window
        self._recent: deque[np.ndarray] = deque(maxlen=window)
        self._sum: np.ndarray | None = None
        self._fast: _FastNll | None = None  # the model's forward pass, buffers of its own: built on first use
        self._centre: np.ndarray | None = None  # the residuals' buffers (with _spread, ...): built on first use

    def __getstate__(self) -> dict[str, Any]:
        return self.__dict__ | {"_fast": None, "_centre": None}  # its buffers are views of one another (see DynamicsDetector)

    def read_from(self, dynamics: DynamicsDetector) -> None:
        """Read ``dynamics``' model, if it is this detector's (the same object, or the same settings and
        weights: a set loaded from files holds a copy of each): its forward pass of a step then
        serves both."""
        if self.model is dynamics or self.model is None or not dynamics.fitted:
            return
        mine, theirs = self.model.tensors(), dynamics.tensors()
        if self.model.config() == dynamics.config() and mine.keys() == theirs.keys() \
                and all(np.array_equal(mine[key], theirs[key]) for key in mine):
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
        self._fast = None
        return self

    def reset(self) -> None:
        self._recent.clear()
        self._sum = None

    def score(self, context: StepContext) -> float:
        """The largest ``|sum of the last residuals| / sqrt(n)`` over readings (an episode's first
        step, and the first after a reading that was not finite: 0, the bias of nothing seen)."""
        self.check_fitted()
        if context.prev_obs is None:
            self.reset()
            return 0.0
        residuals = self._residuals(context).copy()
        recent, total = self._recent, self._sum
        if total is None:
            total = self._sum = np.zeros(len(residuals))  # float64: the running sum does not drift
            self._magnitude = np.empty_like(total)
        if len(recent) == self.window:
            total -= recent[0]  # what append() pushes out
        recent.append(residuals)
        total += residuals
        return float(np.abs(total, out=self._magnitude).max()) / math.sqrt(len(recent))

    def _residuals(self, context: StepContext) -> np.ndarray:
        """:meth:`DynamicsDetector.standardized_residuals` of the step's transition, from the model's
        fast forward pass (equal up to float32 rounding; ``benchmarks/drift_step.py`` times it): the
        pass the dynamics detector just made of this very step where it did (the set's detector, on
        the same weights: :meth:`read_from`), else one of its own. The pass leaves each member's
        mean, its variance over the floor ``w`` and the change, all in units of ``exp(min_logvar /
        2)``: the residual, a ratio, is the same in them. Written into buffers allocated once, as
        the pass itself is."""
        model = self.model
        if model.scored is context and model._fast is not None:
            fast = model._fast
        else:
            fast = self._fast
            if fast is None:
                fast = self._fast = _FastNll(model)
            prev_obs, obs = context.prev_obs, context.obs
            if model.flatten:
                prev_obs, obs = np.ravel(prev_obs), np.ravel(obs)
            fast(prev_obs, context.prev_action, obs)
        if self._centre is None:
            d = fast.d
            self._centre, self._spread, self._w_sum, self._residual = (np.empty(d, np.float32) for _ in range(4))
            self._deviation = np.empty_like(fast.mean)
            self._inv_members = np.float32(fast.inv_members)
        centre, spread, deviation = self._centre, self._spread, self._deviation
        np.add.reduce(fast.mean, 0, out=centre)
        centre *= self._inv_members  # the mixture's mean
        np.subtract(fast.mean, centre, out=deviation)
        deviation *= deviation
        np.add.reduce(deviation, 0, out=spread)
        spread += np.add.reduce(fast.w, 0, out=self._w_sum)
        spread *= self._inv_members  # the mixture's variance: the members' own, and their spread
        np.sqrt(spread, out=spread)
        residual = np.subtract(fast.target, centre, out=self._residual)
        residual /= spread
        return residual

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
