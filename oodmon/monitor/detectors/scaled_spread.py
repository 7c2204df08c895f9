"""``scaled_spread``: an ensemble actor's spread before its tanh, each member's output over its own ID scale.

``pre_squash_std`` is a std over the members, so one member that saturates its torque on ID states
(its output before the tanh far out, where the others sit near 0) widens the spread of every ID
step and hides the shift. This detector divides each member's output by that member's median
|output| over ID steps before taking the std, which puts a saturating member on the others'
footing. On the Pendulum ensembles (``scripts/member_spread.py``, the sweeps' 10 ID and 5 shifted
episodes; README, "Why more members score worse") every trial, of 5 members or 20, read 0.940-0.956
per step on ``l=0.1`` and 0.927-0.942 on ``m=0.05`` so, where ``pre_squash_std`` read 0.652-0.951
and 0.509-0.902.

It needs the members' outputs before the tanh (:attr:`Estimate.pre_squash`): an ensemble of
oodmon whose actors end in tanh (DDPG). MC samples are not members (sample k is another network at
every step), so :func:`~oodmon.monitor.detectors.fit_detectors` refuses it for MC agents.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError
from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory

__all__ = ["ScaledSpreadDetector"]

#: A member's scale is at least this fraction of the largest member's, so that a member whose ID
#: outputs sit at 0 does not divide by 0 (measured scales span 0.07 to 17 within one ensemble).
SCALE_FLOOR = 1e-3


class ScaledSpreadDetector(Detector):
    """The std over an ensemble's members of their outputs before the tanh, each over its ID scale.

    Example:
        >>> import numpy as np
        >>> from oodmon.agents.estimators import Estimate
        >>> ids = [Trajectory(np.zeros((3, 3)), np.zeros((2, 1)), pre_squash=np.array([[[1.0], [10.0]]] * 2))]
        >>> detector = ScaledSpreadDetector().fit(ids)  # member scales 1 and 10
        >>> est = Estimate(np.zeros((1, 1)), np.zeros((2, 1, 1)), np.zeros((1, 1)), np.zeros((1, 1)),
        ...                pre_squash=np.array([[[1.0]], [[-10.0]]]))
        >>> round(detector.score(StepContext(np.zeros(3), np.zeros(1), est)), 6)  # outputs 1 and -1: std 1
        1.0
    """

    name = "scaled_spread"
    needs_estimate = True
    learned = True

    def __init__(self) -> None:
        self._scales: np.ndarray | None = None  # (K, n): each member's median |output| at ID steps
        self._inverse: np.ndarray | None = None

    @property
    def fitted(self) -> bool:
        return self._scales is not None

    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> ScaledSpreadDetector:
        """Each member's scale: its median |output before the tanh| over the steps of ID ``trajectories``.

        Raises:
            ConfigError: the trajectories carry no outputs before a tanh (the policy has none).
        """
        if not trajectories or any(t.pre_squash is None for t in trajectories):
            raise ConfigError("the scaled_spread detector needs an ensemble actor's outputs before its tanh at ID "
                              "steps; this policy gives none (an oodmon DDPG ensemble does)")
        outputs = np.concatenate([t.pre_squash for t in trajectories]).astype(np.float64)  # (T, K, n)
        self._set(np.median(np.abs(outputs), axis=0).astype(np.float32))
        return self

    def _set(self, scales: np.ndarray) -> None:
        if scales.ndim != 2 or not np.all(np.isfinite(scales)) or np.any(scales < 0):
            raise ConfigError(f"the scaled_spread detector's scales must be finite, >= 0 and of shape (members, "
                              f"actions); got shape {scales.shape}")
        floor = max(SCALE_FLOOR * float(scales.max(initial=0.0)), np.finfo(np.float32).tiny)
        self._scales = scales
        self._inverse = (1.0 / np.maximum(scales, floor)).astype(np.float32)

    def score(self, context: StepContext) -> float:
        self.check_fitted()
        estimate = context.estimate
        if estimate is None or estimate.pre_squash is None:
            raise ConfigError("the scaled_spread detector needs the policy's samples before its tanh (an oodmon "
                              "DDPG ensemble); this policy gives none")
        outputs = estimate.pre_squash[:, 0]  # (K, n)
        if outputs.shape != self._inverse.shape:
            raise ConfigError(f"this scaled_spread detector was fitted on {self._inverse.shape[0]} members of "
                              f"{self._inverse.shape[1]} action(s); the policy gives {outputs.shape} (another policy?)")
        return float((outputs * self._inverse).std(axis=0).mean())

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {"scales": self._scales}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> ScaledSpreadDetector:
        detector = cls(**config)
        if "scales" not in tensors:
            raise ConfigError("the scaled_spread detector's tensors are incomplete (no scales)")
        detector._set(np.asarray(tensors["scales"], np.float32))
        return detector
