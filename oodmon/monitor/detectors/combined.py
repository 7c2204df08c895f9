"""``combined``: one score from several detectors, each read as its rank among ID scores.

No single detector wins everywhere (dynamics sees changed physics, the spread sees Pendulum's
``max_speed``, features see corrupted frames), and their scores live on unrelated scales. Each
member's score ``s`` becomes its conformal p-value against that member's scores at held-out ID
steps, ``p = (1 + #{ID scores >= s}) / (n + 1)``, and the combined score is the largest
``-log10 p`` over members (the smallest p-value: what Bonferroni's rule looks at). Beyond the
largest ID score every p-value is the same ``1 / (n + 1)``; there the rank grows on by the
excess over that maximum in units of the member's ID standard deviation, so that a far larger
excursion still ranks higher.

The alarm's threshold is calibrated on the combined score of its own ID episodes like any other
score, so its per-episode false-alarm guarantee is exact whatever the members' dependence.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError
from oodmon.monitor.detectors.base import Detector, StepContext

__all__ = ["CombinedDetector"]


class CombinedDetector(Detector):
    """The largest ID rank (``-log10`` conformal p-value) of the member detectors' scores.

    Args:
        members: names of the detectors it combines; they are computed before it at each step.

    Example:
        >>> combined = CombinedDetector(["a", "b"]).fit_reference({"a": np.arange(99.0), "b": np.zeros(99)})
        >>> round(combined.score(StepContext(np.zeros(1), 0, scores={"a": 49.5, "b": 0.0})), 3)  # p = 50/100
        0.301
    """

    name = "combined"
    learned = True

    def __init__(self, members: Sequence[str]) -> None:
        if not members or len(set(members)) != len(members) or "combined" in members:
            raise ConfigError(f"a combined detector needs distinct member detectors other than itself; got {members!r}")
        self.members = list(members)
        self._reference: dict[str, np.ndarray] | None = None
        self._scale: dict[str, float] = {}

    @property
    def fitted(self) -> bool:
        return self._reference is not None

    def fit_reference(self, scores: Mapping[str, np.ndarray]) -> CombinedDetector:
        """Take each member's scores at held-out ID steps (not the steps it was fitted on).

        Raises:
            ConfigError: a member without scores, or with non-finite ones.
        """
        reference = {}
        for name in self.members:
            # float32, as saved: a loaded detector ranks exactly as the fitted one
            values = np.sort(np.asarray(scores.get(name, []), dtype=np.float32)).astype(np.float64)
            if len(values) < 2 or not np.all(np.isfinite(values)):
                raise ConfigError(f"the combined detector needs finite ID scores of {name!r} at two or more steps")
            reference[name] = values
        self._set_reference(reference, {name: float(values.std()) or 1.0 for name, values in reference.items()})
        return self

    def _set_reference(self, reference: dict[str, np.ndarray], scale: dict[str, float]) -> None:
        self._reference, self._scale = reference, scale
        # What score() reads for each member, in one tuple (no dict look-ups at a step but the
        # score's): the ID scores as a list (bisect on a list costs a tenth of np.searchsorted on
        # a scalar), the rank of each of their n + 1 positions computed once, the largest ID
        # score and the scale of the excess beyond it.
        self._ranked = []
        for name in self.members:
            values = reference[name].tolist()
            n = len(values)
            ranks = [-math.log10((1 + n - position) / (n + 1)) for position in range(n + 1)]
            self._ranked.append((name, values, ranks, values[-1], scale[name]))
        self._by_name = {entry[0]: entry for entry in self._ranked}

    def rank(self, name: str, value: float) -> float:
        """``-log10`` of ``value``'s conformal p-value among the ID scores of member ``name``, grown
        beyond the largest by the excess in units of the member's ID standard deviation."""
        _, values, ranks, top, scale = self._by_name[name]
        rank = ranks[bisect_left(values, value)]
        return rank + (value - top) / scale if value > top else rank

    def score(self, context: StepContext) -> float:
        self.check_fitted()
        scores = context.scores
        try:
            # rank() of each member, written out: one call fewer per member at every step
            return max([ranks[bisect_left(values, value)] + (value - top) / scale if (value := scores[name]) > top
                        else ranks[bisect_left(values, value)] for name, values, ranks, top, scale in self._ranked])
        except KeyError:
            missing = [m for m in self.members if m not in scores]
            if not missing:
                raise
            raise ConfigError(f"the combined detector needs the scores of {', '.join(missing)} at each step; the "
                              "monitor does not compute them") from None

    def config(self) -> dict[str, Any]:
        return {"members": self.members, "scale": self._scale}

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {f"reference.{name}": values.astype(np.float32) for name, values in self._reference.items()}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> CombinedDetector:
        detector = cls(config["members"])
        try:
            reference = {name: np.asarray(tensors[f"reference.{name}"], np.float64) for name in detector.members}
        except KeyError as error:
            raise ConfigError(f"the combined detector's tensors lack the ID scores of {error}") from None
        detector._set_reference(reference, {name: float(config.get("scale", {}).get(name, 1.0))
                                            for name in detector.members})
        return detector

