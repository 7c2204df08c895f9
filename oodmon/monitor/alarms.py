"""The alarm rule and the alarms it raises.

An alarm is raised when the score stays above the threshold for ``consecutive`` steps in a row
(m). The default m = 3 trades two steps of delay for robustness: MC and ensemble scores are noisy
step to step, and a single noisy step should not page anyone. The calibration's false-alarm
guarantee holds for any m, because it is computed for the rule as a whole (see ``threshold``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from oodmon.errors import InvalidParameterError

__all__ = ["DEFAULT_CONSECUTIVE", "AlarmEvent", "AlarmTracker", "check_consecutive", "episode_statistic"]

DEFAULT_CONSECUTIVE = 3


def check_consecutive(consecutive: object) -> int:
    """``consecutive`` as an int >= 1, or :class:`InvalidParameterError`."""
    if isinstance(consecutive, bool) or not isinstance(consecutive, (int, np.integer)) or consecutive < 1:
        raise InvalidParameterError(
            f"consecutive={consecutive!r} is not allowed; the alarm rule needs an integer >= 1 of steps in a row"
        )
    return int(consecutive)


def episode_statistic(scores: np.ndarray, consecutive: int) -> float:
    """The largest t such that the scores stay >= t for ``consecutive`` steps in a row.

    An episode raises an alarm under threshold ``thr`` exactly when this statistic exceeds
    ``thr``, so calibrating on it calibrates the whole rule. ``-inf`` for an episode shorter
    than ``consecutive``.

    Example:
        >>> episode_statistic(np.array([0.1, 0.9, 0.8, 0.2, 0.7]), 2)
        0.8
    """
    scores = np.asarray(scores, dtype=np.float64)
    if len(scores) < consecutive:
        return float("-inf")
    return float(sliding_window_view(scores, consecutive).min(axis=1).max())


@dataclass(frozen=True)
class AlarmEvent:
    """An alarm: the score stayed above the threshold for ``consecutive`` steps.

    Attributes:
        episode: the episode's index in the run.
        step: the step at which the rule fired (the last of the consecutive steps).
        score: that step's score.
        threshold: the threshold in force.
        rule: the rule, e.g. ``"score > threshold for 3 consecutive steps"``.
    """

    episode: int
    step: int
    score: float
    threshold: float
    rule: str


class AlarmTracker:
    """Applies the alarm rule step by step within an episode.

    ``update`` returns whether the rule holds at this step (the score has been above the
    threshold for at least ``consecutive`` steps) and, when it starts to hold, an
    :class:`AlarmEvent`: one event per excursion above the threshold.

    Example:
        >>> tracker = AlarmTracker(threshold=1.0, consecutive=2)
        >>> [tracker.update(0, step, s)[0] for step, s in enumerate([2.0, 0.5, 2.0, 3.0, 4.0])]
        [False, False, False, True, True]
    """

    def __init__(self, threshold: float, consecutive: int = DEFAULT_CONSECUTIVE) -> None:
        self.threshold = float(threshold)
        self.consecutive = check_consecutive(consecutive)
        self.rule = f"score > threshold for {self.consecutive} consecutive steps"
        self._run = 0

    def reset(self) -> None:
        """Start a new episode."""
        self._run = 0

    def update(self, episode: int, step: int, score: float) -> tuple[bool, AlarmEvent | None]:
        self._run = self._run + 1 if score > self.threshold else 0
        if self._run < self.consecutive:
            return False, None
        event = AlarmEvent(episode, step, float(score), self.threshold, self.rule) if self._run == self.consecutive else None
        return True, event
