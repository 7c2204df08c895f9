"""``spread``: the spread of the policy's own samples (the paper's signal), one of :data:`SCORES`."""

from __future__ import annotations

from typing import Any

from oodmon.errors import ConfigError
from oodmon.monitor.detectors.base import Detector, StepContext
from oodmon.monitor.scores import DEFAULT_SCORE, score_function

__all__ = ["SpreadDetector"]


class SpreadDetector(Detector):
    """The std across the policy's MC or ensemble samples, by the named score.

    Args:
        score: ``chosen_std`` (the paper's), ``mean_std``, ``max_std``, ``margin_std`` or ``pre_squash_std``.

    Example:
        >>> import numpy as np
        >>> from oodmon.agents.estimators import Estimate
        >>> est = Estimate(np.array([1]), np.zeros((2, 1, 2)), np.zeros((1, 2)), np.array([[0.5, 2.0]]))
        >>> SpreadDetector("chosen_std").score(StepContext(np.zeros(4), 1, est))
        2.0
    """

    name = "spread"
    needs_estimate = True

    def __init__(self, score: str = DEFAULT_SCORE) -> None:
        self._function = score_function(score)
        self.score_name = score

    def score(self, context: StepContext) -> float:
        if context.estimate is None:
            raise ConfigError("the spread detector needs the policy's samples (an ensemble or MC agent); a plain "
                              "policy has none: use the dynamics detector")
        return float(self._function(context.estimate)[0])

    def config(self) -> dict[str, Any]:
        return {"score": self.score_name}
