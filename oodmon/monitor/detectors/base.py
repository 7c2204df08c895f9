"""The detector seam: what a detector sees at a step, and what it must do.

A detector turns one monitored step into one number, higher meaning further from the ID world.
The :class:`~oodmon.monitor.Monitor` calls :meth:`Detector.reset` at each episode start and
:meth:`Detector.score` at each step with a :class:`StepContext`; learned detectors are fitted
on ID episodes first (:meth:`Detector.fit`, usually through
:func:`~oodmon.monitor.detectors.fit_detectors`). A detector's state is numbers only: arrays
(saved as safetensors) and a JSON object, so a fitted detector loads without running code.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.validation import MOST_STEPS, is_step_count

if TYPE_CHECKING:  # importing it would load torch
    from oodmon.agents.estimators import Estimate

__all__ = ["Detector", "RecentMean", "RunningMean", "StepContext", "Trajectory", "standardise_early"]


class RecentMean:
    """The mean of the last ``window`` values added since :meth:`clear` (of all of them while
    fewer have come): a detector's score over the episode's recent steps.

    Example:
        >>> recent = RecentMean(2)
        >>> [recent.add(v) for v in (1.0, 3.0, 5.0)]
        [1.0, 2.0, 4.0]
    """

    def __init__(self, window: int) -> None:
        if not is_step_count(window):
            raise InvalidParameterError(f"window={window!r} is not allowed; it must be an integer from 1 to {MOST_STEPS:,}")
        self.window = window
        self._values: deque[float] = deque(maxlen=window)

    def clear(self) -> None:
        self._values.clear()

    def fill(self, value: float) -> None:
        """Start again from a full window of ``value`` (a typical ID value: a first odd step is then
        not a window's mean on its own)."""
        self.clear()
        for _ in range(self.window):
            self.add(value)

    def __len__(self) -> int:
        """How many values the mean covers: ``window`` at most."""
        return len(self._values)

    def add(self, value: float) -> float:
        self._values.append(value)
        return sum(self._values) / len(self._values)


def standardise_early(mean: float, count: int, window: int, centre: float) -> float:
    """A window's ``mean`` over ``count`` < ``window`` values moved toward ``centre`` by
    ``sqrt(count / window)``: for independent values about ``centre``, a spread like a full
    window's mean has. Unmoved at ``count >= window``.

    Just after a reset a detector's mean covers few steps, and a mean of few is noisier: on the
    shipped CartPole ensemble's dynamics detector 50 of 50 calibration episodes peaked in their
    first 20 steps (whose transitions are rarer too), and those peaks set the threshold for whole
    episodes (see :class:`~oodmon.monitor.detectors.dynamics.DynamicsDetector`'s ``early``).

    Example:
        >>> standardise_early(3.0, 5, 20, 1.0)  # 1 + (3 - 1) * sqrt(5 / 20)
        2.0
        >>> standardise_early(3.0, 20, 20, 1.0)
        3.0
    """
    if count >= window:
        return mean
    return centre + (mean - centre) * math.sqrt(count / window)


class RunningMean(RecentMean):
    """:class:`RecentMean` kept as a running sum, so that a step costs the same at any window (the
    combined detector's mean over an episode's last 500 steps). Its last bits can differ from
    :class:`RecentMean`'s, which sums its window anew: the detectors' own 20-step means stay that.

    Example:
        >>> mean = RunningMean(2)
        >>> [mean.add(v) for v in (1.0, 3.0, 5.0)]
        [1.0, 2.0, 4.0]
    """

    def __init__(self, window: int) -> None:
        super().__init__(window)
        self._sum = 0.0

    def clear(self) -> None:
        super().clear()
        self._sum = 0.0

    def add(self, value: float) -> float:
        values = self._values
        evicted = values[0] if len(values) == self.window else None  # what append() pushes out
        values.append(value)
        self._sum += value
        if evicted is not None:
            self._sum -= evicted
        return self._sum / len(values)

    def along(self, values: np.ndarray) -> np.ndarray:
        """The means at each step of one episode's ``values``, from a clear start (cleared after)."""
        self.clear()
        out = np.array([self.add(float(v)) for v in values])
        self.clear()
        return out


@dataclass(frozen=True)
class StepContext:
    """What a detector may look at when it scores a step.

    Attributes:
        obs: the observation the policy acts on at this step (one observation, not a batch).
        action: the action deployed at this step (an int, or an array for continuous actions).
        estimate: the policy's :class:`~oodmon.agents.estimators.Estimate` at ``obs`` (a batch of
            one), or ``None`` for a plain policy without samples.
        prev_obs: the previous step's observation (``None`` at an episode's first step).
        prev_action: the action deployed at the previous step (``None`` at the first step).
        scores: the scores of the detectors computed before this one at this step, by name.
        picture: the step's picture where ``obs`` is not it: a dict observation's first picture,
            whose vectors are ``obs`` (:mod:`oodmon.agents.dict_pictures`); else ``None``.
    """

    obs: np.ndarray
    action: Any
    estimate: Estimate | None = None
    prev_obs: np.ndarray | None = None
    prev_action: Any = None
    scores: Mapping[str, float] = field(default_factory=dict)
    picture: np.ndarray | None = None

    @property
    def seen(self) -> np.ndarray:
        """What the step's camera shows: ``picture`` where the step has one beside ``obs``, else
        ``obs`` (what ``frames``, ``stillness`` and ``motion`` read)."""
        return self.obs if self.picture is None else self.picture

    @property
    def features(self) -> np.ndarray | None:
        """The policy's deterministic features at ``obs``, (F,), or ``None``."""
        if self.estimate is None or self.estimate.features is None:
            return None
        return self.estimate.features[0]


@dataclass(frozen=True)
class Trajectory:
    """One ID episode of the deployed policy, as the learned detectors are fitted on it.

    Attributes:
        observations: (T + 1, *obs_shape): every observation, the last one after the last action.
        actions: (T,) ints or (T, action_dim) floats: the deployed actions.
        features: (T, F) the policy's features at each acted-on observation, or ``None``.
        member_values: (T, K, n) an ensemble's members' values at each acted-on observation (see
            :func:`~oodmon.monitor.detectors.scaled_spread.member_values`), or ``None``.
        acted_on: (T + 1, ...) the observations the policy acted on where they are not
            ``observations`` (a stack of them, whose newest the detectors read:
            ``Agent.own_observation``), or ``None``.
        pictures: (T + 1, ...) each step's picture where the observations are not pictures: a
            dict observation's first picture, whose vectors are ``observations``; or ``None``.
        estimates: (T,) the estimator's estimate at each acted-on observation, the one the action
            was chosen from (:func:`~oodmon.monitor.detectors.collect` with ``estimates_from``),
            or ``None``: :func:`~oodmon.monitor.detectors.trajectory_scores` then scores those,
            as the monitor scores the estimate it decided from, instead of asking the estimator
            again (an MC estimator with sampled masks would draw other samples).
    """

    observations: np.ndarray
    actions: np.ndarray
    features: np.ndarray | None = None
    member_values: np.ndarray | None = None
    acted_on: np.ndarray | None = None
    pictures: np.ndarray | None = None
    estimates: tuple[Estimate, ...] | None = None

    def __post_init__(self) -> None:
        if len(self.observations) != len(self.actions) + 1:
            raise ConfigError(f"a trajectory holds one observation more than actions; got {len(self.observations)} "
                              f"observations and {len(self.actions)} actions")
        if self.estimates is not None and len(self.estimates) != len(self.actions):
            raise ConfigError(f"a trajectory holds one estimate per action; got {len(self.estimates)} estimates and "
                              f"{len(self.actions)} actions")

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def seen(self) -> np.ndarray:
        """What the camera showed at each step, (T + 1, ...): ``pictures`` where the episode has them
        beside its observations, else ``observations`` (:attr:`StepContext.seen`, step by step)."""
        return self.observations if self.pictures is None else self.pictures


class Detector:
    """Base of the detectors.

    Subclasses set :attr:`name`, implement :meth:`score`, and, when they learn from ID episodes,
    :meth:`fit`, :meth:`state` and :meth:`from_state`.

    Attributes:
        name: the detector's name in step records, threshold files and the CLI.
        needs_estimate: it reads the policy's samples or features (a plain policy has none).
    """

    name: ClassVar[str]
    needs_estimate: ClassVar[bool] = False
    learned: ClassVar[bool] = False

    @property
    def fitted(self) -> bool:
        return True

    def reset(self) -> None:
        """A new episode starts."""

    def score(self, context: StepContext) -> float:
        raise NotImplementedError

    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> Detector:
        """Learn from ID episodes; returns ``self``."""
        return self

    def config(self) -> dict[str, Any]:
        """The JSON part of the detector's state (numbers, strings, lists)."""
        return {}

    def tensors(self) -> dict[str, np.ndarray]:
        """The array part of the detector's state."""
        return {}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> Detector:
        return cls(**config)

    def fingerprint(self) -> str:
        """``sha256:...`` of what the detector learned: its name, settings and arrays, as its files
        hold them (the same before and after a save and a load). A threshold records the fingerprint
        of the detector it was calibrated with, and the monitor refuses another: its scores are on
        another scale."""
        digest = hashlib.sha256(json.dumps([self.name, self.config()], sort_keys=True).encode())
        for key, value in sorted(self.tensors().items()):
            value = np.ascontiguousarray(value)
            digest.update(f"{key} {value.dtype.str} {value.shape}".encode())
            digest.update(value.tobytes())
        return "sha256:" + digest.hexdigest()

    def check_fitted(self) -> None:
        if not self.fitted:
            raise ConfigError(f"the {self.name} detector is not fitted: fit it on ID episodes first "
                              f"(oodmon.monitor.detectors.fit_detectors, or `oodmon fit-detectors`)")
