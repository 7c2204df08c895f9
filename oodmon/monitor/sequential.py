"""Sequential alarm rules: CUSUM and a conformal test martingale on per-step p-values.

These rules first turn each score into a conformal p-value against ID scores of other episodes
(a :class:`Reference`), pooled over the episode or, with ``by_age``, **of the same time since
reset** (buckets of steps), so that a start-up step is compared with start-up steps: the
m-consecutive rule compares raw scores with one threshold for the whole episode, so the steps
whose ID scores run highest (Pendulum's swing-up under the spread score) set it. Then:

- ``cusum``: S_t = max(0, S_{t-1} + (-log10 p_t - 1)). A step adds evidence when p < 0.1 and
  takes some away otherwise; S restarts from 0, so a long normal stretch does not delay the
  alarm. (Page's CUSUM on the p-values' surprise.)
- ``martingale``: the simple-mixture conformal test martingale (Vovk et al., "Testing
  exchangeability on-line", 2003): M_t = integral over e in (0, 1) of prod_i e p_i^(e-1) de,
  reported as log10 M_t. For independent uniform p-values P(sup_t M_t >= 1/a) <= a at every
  stopping time (Ville): anytime-valid. Under ID it decays only like 1/t, so a late shift is
  seen within a few steps.

Both are calibrated as every rule is: the episode statistic is the largest value of S_t (or
log10 M_t) in the episode, and the threshold is the conformal order statistic of the calibration
episodes' statistics (``oodmon.monitor.threshold``). So the false-alarm bound holds whatever
the p-values' dependence within an episode (a step's scores are correlated with its
neighbours', so the martingale's own anytime guarantee would be optimistic). The reference must
come from ID episodes apart from the calibration ones (``calibrate_agent`` plays them with
seeds :data:`oodmon.seeds.REFERENCE`), or the calibration episodes would not be exchangeable with a
fresh one.

Measured (``scripts/compare_rules.py``, ``results/monitor/``): neither rule is a default. On the
learned detectors, whose scores are already 20-step means, a sum accumulates the ID start-up (a
40-60-step run of top-decile scores on Pendulum, its timing varying between episodes), so the
calibrated thresholds sit high and the delays grow; by age is worse still, as the reference's 20
episodes do not cover the start-up's timing. m = 1 consecutive steps alarms first.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError

__all__ = ["RULES", "SEQUENTIAL_RULES", "Reference", "SequentialStatistic", "bucket_edges", "sequential_path"]

#: Every alarm rule: m consecutive steps (with an optional window) and the sequential ones.
RULES = ("consecutive", "cusum", "martingale")
SEQUENTIAL_RULES = ("cusum", "martingale")
#: The CUSUM's drift: a step adds -log10 p - CUSUM_DRIFT (evidence when p < 0.1).
CUSUM_DRIFT = 1.0
#: The mixing grid of the martingale's bets e (midpoints of 200 equal cells of (0, 1)).
_BETS = (np.arange(200) + 0.5) / 200
_LOG_BETS = np.log(_BETS)
#: At most this many ID scores kept per bucket (as evenly spaced order statistics).
_KEEP = 400


def bucket_edges(length: int) -> list[int]:
    """Where the time-since-reset buckets start: every 10 steps up to 100 (the start-up, where
    scores change fastest), then every 100 steps up to ``length``.

    Example:
        >>> bucket_edges(200)
        [0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100]
    """
    edges = list(range(0, min(length, 100), 10))
    edges += list(range(100, length, 100))
    return edges or [0]


class Reference:
    """The ID per-step scores of a detector, pooled or in buckets of time since reset: turns a score
    into a p-value.

    ``p_value(step, score)`` = (1 + n_ge) / (n + 1), where n_ge of the step's bucket's n reference
    scores are >= ``score``: a conformal p-value, uniform (up to ties) when the step is as ID as
    the reference's. Pooled, there is one bucket; by age, :func:`bucket_edges`, and a step past the
    last edge uses the last bucket.

    Example:
        >>> ref = Reference.from_episodes([np.arange(20.0), np.arange(20.0) + 0.5], by_age=True)
        >>> ref.p_value(3, 100.0), ref.p_value(3, -1.0)   # nothing >= 100; everything >= -1
        (0.047619047619047616, 1.0)
    """

    def __init__(self, edges: Sequence[int], values: Sequence[np.ndarray], counts: Sequence[int]) -> None:
        if len(edges) != len(values) or len(edges) != len(counts) or not len(edges) or list(edges) != sorted(edges):
            raise ConfigError("a reference needs ascending bucket edges, each with its sorted scores and count")
        if any(len(v) == 0 for v in values):
            raise ConfigError("a reference bucket has no ID scores; play longer or more reference episodes")
        self.edges = np.asarray(edges, dtype=np.int64)
        self.values = [np.sort(np.asarray(v, dtype=np.float64)) for v in values]
        self.counts = [int(c) for c in counts]

    @classmethod
    def from_episodes(cls, episodes: Sequence[np.ndarray], *, by_age: bool = False) -> Reference:
        """From the per-step scores of ID reference episodes: one pool, or ``by_age`` one per
        bucket of time since reset (:func:`bucket_edges`)."""
        episodes = [np.asarray(e, dtype=np.float64) for e in episodes if len(e)]
        if not episodes:
            raise ConfigError("a reference needs ID episodes with at least one step")
        edges = bucket_edges(max(len(e) for e in episodes)) if by_age else [0]
        values, counts = [], []
        for low, high in zip(edges, [*edges[1:], None]):  # every edge is below the longest episode's length
            found = np.sort(np.concatenate([e[low:high] for e in episodes]))
            counts.append(len(found))
            keep = found if len(found) <= _KEEP else found[np.linspace(0, len(found) - 1, _KEEP).round().astype(int)]
            values.append(keep)
        return cls(edges, values, counts)

    def _bucket(self, step: int | np.ndarray) -> np.ndarray:
        return np.searchsorted(self.edges, step, side="right") - 1

    def p_values(self, scores: np.ndarray, first_step: int = 0) -> np.ndarray:
        """The p-value of each of ``scores`` (steps ``first_step``, ``first_step + 1``, ...)."""
        scores = np.asarray(scores, dtype=np.float64)
        buckets = self._bucket(np.arange(first_step, first_step + len(scores)))
        out = np.empty(len(scores))
        for b in np.unique(buckets):
            mask = buckets == b
            kept, n = self.values[b], self.counts[b]
            at_least = (len(kept) - np.searchsorted(kept, scores[mask], side="left")) * (n / len(kept))
            out[mask] = (1.0 + at_least) / (n + 1.0)
        return out

    def p_value(self, step: int, score: float) -> float:
        """:meth:`p_values` of one step (the monitor's path: no arrays built)."""
        b = int(np.searchsorted(self.edges, step, side="right")) - 1
        kept, n = self.values[b], self.counts[b]
        at_least = (len(kept) - int(np.searchsorted(kept, score, side="left"))) * (n / len(kept))
        return (1.0 + at_least) / (n + 1.0)

    def to_dict(self) -> dict[str, Any]:
        return {"edges": self.edges.tolist(), "counts": self.counts, "values": [v.tolist() for v in self.values]}

    @classmethod
    def from_dict(cls, data: Any) -> Reference:
        """Raises:
            ConfigError: not a reference written by :meth:`to_dict`."""
        try:
            values = [np.asarray(v, dtype=np.float64) for v in data["values"]]
            reference = cls(list(data["edges"]), values, list(data["counts"]))
        except (KeyError, TypeError, ValueError) as error:
            raise ConfigError(f"the threshold's reference is damaged ({type(error).__name__}: {error})") from None
        if any(not np.isfinite(v).all() for v in values) or any(c < len(v) for c, v in zip(reference.counts, values)):
            raise ConfigError("the threshold's reference has non-finite scores or counts below its kept scores")
        return reference


class SequentialStatistic:
    """A sequential rule's statistic, step by step within an episode (``reset`` at each start).

    Example:
        >>> stat = SequentialStatistic("cusum", Reference.from_episodes([np.zeros(50)] * 9))
        >>> [round(stat.update(s, 5.0), 2) for s in range(3)]  # above all 450 ID scores: p = 1/451, +1.65 a step
        [1.65, 3.31, 4.96]
        >>> round(stat.update(3, 0.0), 2)  # an ordinary step (p = 1): -1
        3.96
    """

    def __init__(self, rule: str, reference: Reference) -> None:
        if rule not in SEQUENTIAL_RULES:
            raise InvalidParameterError(f"rule={rule!r} is not a sequential rule; use {' or '.join(SEQUENTIAL_RULES)}")
        self.rule, self.reference = rule, reference
        self.reset()

    def reset(self) -> None:
        self._value = 0.0
        self._steps = 0
        self._log_p = 0.0  # the sum of ln p_i (martingale)

    def update(self, step: int, score: float) -> float:
        """The statistic after the score of ``step``: S_t (cusum) or log10 M_t (martingale)."""
        p = self.reference.p_value(step, score) if math.isfinite(score) else 1.0
        if self.rule == "cusum":
            self._value = max(0.0, self._value - math.log10(p) - CUSUM_DRIFT)
            return self._value
        self._steps += 1
        self._log_p += math.log(p)
        # ln of the mixture: log-mean-exp over the bets of t ln e + (e - 1) sum ln p.
        terms = self._steps * _LOG_BETS + (_BETS - 1.0) * self._log_p
        top = terms.max()
        self._value = float((top + math.log(np.exp(terms - top).mean())) / math.log(10))
        return self._value


def sequential_path(rule: str, reference: Reference, scores: np.ndarray) -> np.ndarray:
    """The statistic after each step of an episode's ``scores``: what :class:`SequentialStatistic`
    computes online, for a whole episode at once (calibration reduces thousands of episodes)."""
    if rule not in SEQUENTIAL_RULES:
        raise InvalidParameterError(f"rule={rule!r} is not a sequential rule; use {' or '.join(SEQUENTIAL_RULES)}")
    scores = np.asarray(scores, dtype=np.float64)
    p = np.where(np.isfinite(scores), reference.p_values(np.nan_to_num(scores)), 1.0)
    if rule == "cusum":
        path, value = np.empty(len(p)), 0.0
        for t, x in enumerate((-np.log10(p) - CUSUM_DRIFT).tolist()):
            value = max(0.0, value + x)
            path[t] = value
        return path
    steps = np.arange(1, len(p) + 1)[:, None]
    terms = steps * _LOG_BETS + (_BETS - 1.0) * np.cumsum(np.log(p))[:, None]
    top = terms.max(axis=1, keepdims=True)
    return ((top + np.log(np.exp(terms - top).mean(axis=1, keepdims=True)))[:, 0]) / math.log(10)
