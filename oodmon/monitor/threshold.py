"""Thresholds calibrated on in-distribution episodes only, with a false-alarm bound.

Episode mode (the default): each held-out ID calibration episode gives one number, the
:func:`~oodmon.monitor.alarms.episode_statistic` of its scores under the alarm rule; an episode
alarms exactly when that number exceeds the threshold. The threshold is the k-th smallest of the
n numbers, and the rank k decides what is promised about a fresh ID episode that is exchangeable
with the calibration ones:

- **For the threshold you got** (``confidence = 1 - d``, the default 0.9): k is the smallest rank
  with P(Binomial(n, 1 - a) <= k - 1) >= 1 - d. Then, with probability at least 1 - d over the
  draw of the calibration episodes, *this* threshold's false-alarm rate is at most a
  (training-conditional conformal prediction, Vovk 2012): if the k-th smallest of n uniform
  ranks is >= 1 - a, at most a of the fresh episodes' mass lies above it. It needs
  n >= log(d) / log(1 - a) episodes (45 for a = 0.05, d = 0.1; 22 for a = 0.1).
- **On average over calibrations** (``confidence=None``): k = ceil((n + 1)(1 - a)), split
  conformal prediction; the rate averaged over calibration sets is at most a, but one threshold
  file's rate can be several times a (for n = 50, a = 0.05, about a quarter of the thresholds
  exceed a). It needs n >= 1/a - 1 (19 for a = 0.05).

Ties among the statistics only make either promise more conservative.

With a ``window`` (see ``alarms``) the statistic is taken over the trailing means of the scores;
the promise is the same, for that rule.

Step mode (rule m = 1, no window) bounds the share of ID steps above the threshold, for comparison
with the paper, which scores steps. Steps of one episode are above a threshold together, so they
are not the units of the bound: with ``confidence``, the threshold is the lowest score under which
Korn and Graubard's clustered upper limit of that share, each episode a cluster, is at most a
(:func:`step_threshold`; it needs as many episodes as episode mode; a few episodes far above the
rest widen it by Hall's skewness correction). That limit is a large-sample one, so the promise is
approximate, but measured: of 1,000 step-mode thresholds above a = 0.05 at confidence 0.9, 7.7%
of the shipped CartPole ensemble's, 7.4% of the Pendulum ensemble's and 10.1% of the CartPole
DropConnect agent's (the rank over the steps as if independent, before 2026-12-05: 38%, 37% and
41%). With ``confidence=None``, the split-conformal rank over all steps: on average over
calibrations only.
"""

from __future__ import annotations

import json
import math
import shlex
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from oodmon.envs.physics import check_obs_noise
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.hashing import other_weights
from oodmon.jsonfile import read_json, write_json
from oodmon.monitor.alarms import (DEFAULT_CONSECUTIVE, check_consecutive, check_warmup, check_window, episode_statistic,
                                   rule_text)
from oodmon.monitor.sequential import RULES, Reference
from oodmon.names import MASKS
from oodmon.validation import is_whole

__all__ = ["DEFAULT_CONFIDENCE", "EARLY_GAIN", "MODES", "OUTLYING", "WARMUP_HINT", "ClusterSums",
           "ClusteredInterval", "EarlyPeaksWarning", "OutlyingThresholdWarning", "Stretches", "Threshold",
           "calibrate", "check_step_episodes", "clopper_pearson", "clustered_interval", "conformal_rank",
           "episodes_needed", "model_files", "recorded_sb3", "sb3_arguments", "sb3_loading", "step_threshold",
           "verdict_of"]

MODES = ("episode", "step")
#: The detectors a threshold may name (``oodmon.monitor.detectors.DETECTORS``; spelled here so
#: that reading a threshold file does not import them).
DETECTOR_NAMES = ("spread", "dynamics", "features", "frames", "combined", "scaled_spread", "drift", "transitions",
                  "stillness", "motion", "vanishing")
_QUANTILES = (0.5, 0.9, 0.95, 0.99)
#: The default probability that a threshold's false-alarm rate is at most its target.
DEFAULT_CONFIDENCE = 0.9


def _is_fraction(value: object) -> bool:
    """A number strictly between 0 and 1 (not a bool, not NaN)."""
    return (isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
            and 0.0 < value < 1.0)


def _check_far_and_confidence(far: object, confidence: object) -> None:
    """Of calibration's arguments and of a threshold file alike."""
    if not _is_fraction(far):
        raise InvalidParameterError(f"far={far!r} is not allowed; the target false-alarm rate must satisfy 0 < far < 1")
    if confidence is not None and not _is_fraction(confidence):
        raise InvalidParameterError(f"confidence={confidence!r} is not allowed; it must satisfy 0 < confidence < 1, "
                                    "or be None (the rate bounded on average over calibrations only)")


def episodes_needed(far: float, confidence: float | None = DEFAULT_CONFIDENCE) -> int:
    """The fewest calibration episodes for which a threshold exists at ``far`` and ``confidence``.

    Example:
        >>> episodes_needed(0.05, 0.9), episodes_needed(0.05, None), episodes_needed(0.1, 0.9)
        (45, 19, 22)
    """
    _check_far_and_confidence(far, confidence)
    if confidence is None:
        return max(1, math.ceil(1 / far - 1 - 1e-9))
    # The largest statistic (k = n) works once 1 - (1 - far)^n >= confidence.
    n = max(1, math.ceil(math.log(1 - confidence) / math.log(1 - far) - 1e-9))
    while 1 - (1 - far) ** n < confidence:
        n += 1
    return n


def conformal_rank(n: int, far: float, confidence: float | None = DEFAULT_CONFIDENCE, *, unit: str = "episodes") -> int:
    """The rank k (1-based, of n ascending statistics) the threshold takes (see the module docstring).

    Raises:
        ConfigError: n is too small for ``far`` at ``confidence``; the message says how many are needed.

    Example:
        >>> conformal_rank(50, 0.05, None), conformal_rank(50, 0.05, 0.9), conformal_rank(200, 0.05, 0.9)
        (49, 50, 195)
    """
    _check_far_and_confidence(far, confidence)
    if confidence is None:
        rank = math.ceil((n + 1) * (1 - far))
    else:
        # P(the k-th smallest of n uniforms >= 1 - far) = P(Binomial(n, 1 - far) <= k - 1).
        rank = _smallest_k(n, 1 - far, confidence) + 1
    if rank > n:
        needed = episodes_needed(far, confidence)
        bound = ("for its guarantee" if confidence is None
                 else f"to bound its rate with confidence {confidence:g}")
        raise ConfigError(f"far={far} needs at least {needed} ID calibration {unit} {bound}; got {n}")
    return rank


def clopper_pearson(successes: int, trials: int, level: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) two-sided ``level`` interval of a binomial proportion.

    Example:
        >>> [round(x, 4) for x in clopper_pearson(183, 1200)]
        [0.1326, 0.1741]
    """
    from scipy.special import betaincinv  # the Beta quantile: scipy.stats.beta.ppf's numbers, to the bit

    tail = (1 - level) / 2
    low = 0.0 if successes == 0 else float(betaincinv(successes, trials - successes + 1, tail))
    high = 1.0 if successes == trials else float(betaincinv(successes + 1, trials - successes, 1 - tail))
    return low, high


@dataclass(frozen=True)
class ClusteredInterval:
    """A proportion counted over clusters of units that are not independent of one another (the
    steps or stretches of one episode), with its two-sided interval (:func:`clustered_interval`).

    Attributes:
        successes, trials: summed over the clusters.
        clusters: how many clusters (episodes) they came in.
        design_effect: the variance of the proportion between clusters over a binomial's of as many
            independent units, at least 1 (1: the interval is Clopper-Pearson's of the units, but for
            the degrees of freedom of the clusters).
        low, high: the interval.
    """

    successes: int
    trials: int
    clusters: int
    design_effect: float
    low: float
    high: float


def clustered_interval(counts: Sequence[tuple[int, int]], level: float = 0.95) -> ClusteredInterval:
    """The ``level`` interval of a proportion whose units come in clusters, ``counts`` holding each
    cluster's ``(successes, units)``: Korn and Graubard's (1998) Clopper-Pearson interval on an
    effective sample size, as survey statistics computes it for cluster samples (SAS SURVEYFREQ's
    modified Clopper-Pearson limits, R survey's ``svyciprop(method="beta")`` with the degrees of
    freedom of the clusters). The proportion's variance is the ratio estimator's between clusters,
    m / (m - 1) * sum((s_i - p n_i)^2) / N^2 over m clusters of N units; the effective size is
    p (1 - p) / variance (the units over the design effect, which is taken as at least 1, so that
    the interval is never narrower than Clopper-Pearson's over the units), times (t_{N-1} /
    t_{m-1})^2 at the interval's quantile; the limits are Clopper-Pearson's at that size and p
    times it as the successes. Where no success or no failure was seen, the variance is 0 and the
    effective size is N (Korn and Graubard's choice); one cluster alone is its own single unit.

    Steps of one episode alarm together (the scores are means of the last 20 steps, and a policy
    that has drifted stays drifted), so counted as independent their Clopper-Pearson interval is far
    too narrow. Simulated (each episode's own rate drawn from a Beta of mean 0.08 and intra-episode
    correlation 0.3, 1,000 draws; ``tests/monitor/test_rule_and_calibration.py``): over 40 episodes
    of 10 stretches Clopper-Pearson's 95% interval covered the true rate in 71% of the draws and
    this one in 95%; over the steps of 20 episodes of 500 steps (rate 0.05), 11% against 90%; with
    independent units both cover it (95% and 96%, this one 8% wider). Where a few clusters lie far
    above the rest, the upper limit is widened by their skew beyond what its Clopper-Pearson form
    carries (:func:`_excess_skew_factor`, since 2026-12-06; ``scripts/interval_coverage.py``: over
    200 episodes, 4.4% of the draws below the true rate before, 2.3% since). Its weak side: with no
    alarm at all (or nothing but alarms) there is no spread to measure, and the interval is the
    units' own, as narrow as if they were independent.

    Example:
        >>> kept = clustered_interval([(0, 10)] * 30 + [(10, 10)] * 10)  # 10 of 40 episodes alarm all through
        >>> round(kept.design_effect, 2), [round(x, 3) for x in (kept.low, kept.high)]
        (10.26, [0.122, 0.42])
        >>> [round(x, 3) for x in clopper_pearson(100, 400)]  # the same 400 units as if independent
        [0.208, 0.295]
        >>> round(clustered_interval([(1, 1)] * 3 + [(0, 1)] * 37).design_effect, 3)  # one unit a cluster: 40 / 39
        1.026
    """
    sums = ClusterSums()
    for successes, units in counts:
        sums.add(successes, units)
    return sums.interval(level)


class ClusterSums:
    """Running sums of clusters' ``(successes, units)``: what :func:`clustered_interval` needs of
    them, in constant memory (``oodmon run`` counts each episode's stretches so over weeks), the
    sums exact integers.

    Example:
        >>> sums = ClusterSums()
        >>> for episode in [(0, 10)] * 30 + [(10, 10)] * 10:
        ...     sums.add(*episode)
        >>> sums.interval() == clustered_interval([(0, 10)] * 30 + [(10, 10)] * 10)
        True
    """

    def __init__(self) -> None:
        self.clusters = self.successes = self.trials = 0
        self._ss = self._sn = self._nn = 0  # sums of s^2, s n and n^2 over the clusters
        self._sss = self._ssn = self._snn = self._nnn = 0  # and of s^3, s^2 n, s n^2, n^3 (their skew)

    def add(self, successes: int, units: int) -> None:
        s, n = int(successes), int(units)
        self.clusters += 1
        self.successes += s
        self.trials += n
        self._ss += s * s
        self._sn += s * n
        self._nn += n * n
        self._sss += s * s * s
        self._ssn += s * s * n
        self._snn += s * n * n
        self._nnn += n * n * n

    def interval(self, level: float = 0.95) -> ClusteredInterval:
        """:func:`clustered_interval` of the clusters added."""
        successes, trials, clusters = self.successes, self.trials, self.clusters
        if trials == 0:
            raise ValueError("no units to count")
        tail = (1 - level) / 2
        if clusters < 2:  # no spread between clusters to measure: the one cluster is one unit
            low, high = clopper_pearson(int(successes > 0), 1, level)
            return ClusteredInterval(successes, trials, clusters, float(trials), low, high)
        if successes in (0, trials):
            return ClusteredInterval(successes, trials, clusters, 1.0, *clopper_pearson(successes, trials, level))
        # sum((s_i - rate n_i)^2) * N^2, in integers: N^2 sum(s^2) - 2 S N sum(s n) + S^2 sum(n^2)
        spread = trials * trials * self._ss - 2 * successes * trials * self._sn + successes * successes * self._nn
        design_effect, low, high = _korn_graubard(successes, trials, clusters, spread / trials ** 2, tail)
        # the upper limit widened where the clusters' shares are skewed to the right (_excess_skew_factor):
        # sum((s_i - rate n_i)^3) * N^3 = N^3 sum(s^3) - 3 S N^2 sum(s^2 n) + 3 S^2 N sum(s n^2) - S^3 sum(n^3)
        cubed = (trials ** 3 * self._sss - 3 * successes * trials ** 2 * self._ssn
                 + 3 * successes ** 2 * trials * self._snn - successes ** 3 * self._nnn)
        skew = (cubed / trials ** 3 / clusters) / (spread / trials ** 2 / clusters) ** 1.5 if spread > 0 else 0.0
        factor = _excess_skew_factor(skew, clusters, successes / trials, trials / float(design_effect), tail)
        if factor > 1:
            _, _, high = _korn_graubard(successes, trials, clusters, spread / trials ** 2 * factor, tail)
        return ClusteredInterval(successes, trials, clusters, float(design_effect), float(low), float(high))


def _korn_graubard(successes: Any, trials: int, clusters: int, spread: Any, tail: float,
                   freedom: float | None = None) -> tuple[Any, Any, Any]:
    """:func:`clustered_interval`'s design effect and limits (each tail ``tail``) of ``successes``
    of ``trials`` units in ``clusters`` clusters whose ``sum((s_i - rate n_i)^2)`` is ``spread``;
    ``successes`` and ``spread`` numbers or arrays alike, none of the successes 0 or ``trials``;
    ``freedom``: the degrees of freedom (default: ``clusters - 1``)."""
    from scipy.special import betaincinv, stdtrit

    rate = np.asarray(successes) / trials
    variance = clusters / (clusters - 1) * np.asarray(spread) / trials ** 2
    design_effect = np.maximum(1.0, variance / (rate * (1 - rate) / trials))
    freedom = clusters - 1 if freedom is None else freedom
    # (at the median both quantiles are 0: their ratio's limit there, read just beside it; found by
    # scripts/fuzz_api.py, a ZeroDivisionError of calibrate(mode="step", confidence=0.5))
    quantile = 1 - tail if abs(tail - 0.5) > 1e-9 else 0.5 + 1e-6
    degrees = (float(stdtrit(trials - 1, quantile)) / float(stdtrit(freedom, quantile))) ** 2 if trials > 1 else 1.0
    size = trials / design_effect * degrees
    hits = rate * size
    return design_effect, betaincinv(hits, size - hits + 1, tail), betaincinv(hits + 1, size - hits, 1 - tail)


def check_step_episodes(n: int, far: float, confidence: float) -> None:
    """Refuse fewer calibration episodes than :func:`step_threshold` needs for ``far`` at ``confidence``."""
    _check_far_and_confidence(far, confidence)
    needed = episodes_needed(far, confidence)
    if n < needed:
        raise ConfigError(f"far={far} needs at least {needed} ID calibration episodes to bound its rate with "
                          f"confidence {confidence:g} in step mode too, whose steps are counted by episode (those "
                          f"of one episode are above a threshold together); got {n}")


def _skew_factor(residuals: np.ndarray, confidence: float, episodes: float) -> np.ndarray:
    """How much to widen the clustered limit's variance, per row of episodes' ``residuals`` (s_i -
    rate n_i), where their skew is to the right: a few episodes far above the rest (an MC agent's
    sampled spread) make a large-sample limit of their mean undercover. Hall's (1992) correction of
    the one-sided t limit, z + g (2 z^2 + 1) / (6 sqrt(m)) for skewness g over m episodes, taken as
    a factor of the variance, never below 1. Measured on step-mode thresholds of the shipped
    CartPole DropConnect agent (``scripts/step_scores.py``, 1,000 calibrations of 50 episodes, far
    0.05, confidence 0.9; its episodes' shares above the 95th percentile have skewness 3.2): 14.0%
    above far without it, 10.1% with it; the CartPole and Pendulum ensembles' (skewness 1.0) 9.9%
    and 9.9% without, 7.7% and 7.4% with."""
    from scipy.special import ndtri

    z = float(ndtri(confidence)) if confidence > 0.5 else 0.0
    if z <= 0:
        return np.ones(len(residuals))
    second = np.mean(residuals ** 2, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        skew = np.where(second > 0, np.mean(residuals ** 3, axis=1) / second ** 1.5, 0.0)
    return _hall(z, skew, episodes)


def _hall(z: float, skew: Any, terms: float) -> Any:
    """Hall's (1992) correction of a one-sided limit z of a mean over ``terms`` terms of skewness
    ``skew``, z + g (2 z^2 + 1) / (6 sqrt(m)), as a factor of the limit's variance, never below 1
    (a skew to the left leaves it); ``skew`` a number or an array."""
    return np.maximum(1.0, (z + np.maximum(skew, 0.0) * (2 * z * z + 1) / (6 * math.sqrt(terms))) / z) ** 2


def _excess_skew_factor(skew: float, clusters: int, rate: float, size: float, tail: float) -> float:
    """How much to widen the variance of :func:`clustered_interval`'s upper limit (one-sided, the
    ``tail`` above it) where the clusters' shares are skewed to the right beyond what its
    Clopper-Pearson form carries already: :func:`_hall` of the clusters' residual skewness ``skew``
    less what a binomial's of ``size`` units at ``rate`` would give their mean ((1 - 2 p) / sqrt(n p
    (1 - p)), which the Beta limits hold), as the skewness of ``clusters`` terms.
    ``scripts/interval_coverage.py`` measures it."""
    from scipy.special import ndtri

    z = float(ndtri(1 - tail))
    if z <= 0:  # (a limit at or below the median: no tail to correct)
        return 1.0
    binomial = (1 - 2 * rate) / math.sqrt(size * rate * (1 - rate)) * math.sqrt(clusters)
    return float(_hall(z, skew - binomial, clusters))


def step_threshold(episodes: Sequence[np.ndarray], far: float, confidence: float) -> float:
    """The lowest threshold t, of the per-step scores of ID ``episodes``, under which the share of
    steps above any t' >= t is bounded by ``far`` with ``confidence``: the one-sided upper limit of
    :func:`clustered_interval` (at level 2 ``confidence`` - 1, each episode a cluster) of the steps
    above t' is at most ``far`` for every score t' >= t (risk-controlling calibration, Bates et al.
    2021: a bound that holds for each t' alone, read from the top down, holds for the t it stops
    at). With no step above t' there is no spread to measure, and the episodes are the units: the
    highest score is a threshold once ``episodes_needed(far, confidence)`` episodes lie under it.
    The limit's degrees of freedom are Kish's effective number of episodes less one, (sum n)^2 /
    sum n^2 - 1 over episodes of n steps: the episodes less one where they are alike, near none
    where one episode is most of the steps. Its variance is widened where the episodes' shares are
    skewed to the right (:func:`_skew_factor`).

    Steps of one episode are above a threshold together (CartPole's `combined`: design effect 16),
    so the rank over the steps as if each were independent, which this replaced on 2026-12-05, gave
    thresholds above their target far more often than promised: of 1,000 calibrations of 50 episodes
    drawn from 1,000 ID episodes of the shipped CartPole ensemble, 38% against the 10% of confidence
    0.9; this, 7.7% (``scripts/step_scores.py``).

    Raises:
        ConfigError: fewer episodes than ``episodes_needed(far, confidence)``.

    Example:
        >>> rng = np.random.default_rng(0)
        >>> episodes = [rng.normal(rng.normal(), 1, 200) for _ in range(50)]  # each episode its own level
        >>> t = step_threshold(episodes, 0.05, 0.9)
        >>> float(np.mean(np.concatenate(episodes) > t)) < 0.05
        True
    """
    check_step_episodes(len(episodes), far, confidence)
    lengths = np.array([len(scores) for scores in episodes])
    trials, clusters = int(lengths.sum()), len(episodes)
    # Kish's effective number of clusters, (sum n)^2 / sum n^2 (the episodes where they are alike):
    # one episode far longer than the rest is most of the steps, and alone their spread hardly
    # measures (of one episode of 10,000 steps and 49 of one, its last 4.7% passed as bounded)
    freedom = max(trials * trials / float(np.sum(lengths.astype(float) ** 2)) - 1, 1e-9)
    ordered = [np.sort(scores[~np.isnan(scores)]) for scores in episodes]  # (a NaN score is above no threshold)
    candidates = np.unique(np.concatenate(ordered))[::-1]
    if not len(candidates):
        return math.nan
    tail = 1 - confidence
    kept = candidates[0]  # no step above it: the episodes, as many as needed, are the units
    start, size = 0, max(64, math.ceil(1.5 * far * trials))  # (it stops about far * trials candidates down)
    while start < len(candidates):
        chunk = candidates[start:start + size]
        start, size = start + size, 2 * size
        above = np.stack([len(o) - np.searchsorted(o, chunk, side="right") for o in ordered], axis=1)
        successes = above.sum(axis=1)
        counted = successes > 0
        high = np.zeros(len(chunk))
        if counted.any():
            residuals = above[counted] - (successes[counted] / trials)[:, None] * lengths  # s_i - rate n_i
            spread = np.sum(residuals ** 2, axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                _, _, high[counted] = _korn_graubard(successes[counted], trials, clusters,
                                                     spread * _skew_factor(residuals, confidence, freedom + 1), tail,
                                                     freedom)
            high[successes == trials] = 1.0
        failing = np.flatnonzero(~(high <= far))
        if failing.size:
            return float(kept if failing[0] == 0 else chunk[failing[0] - 1])
        kept = chunk[-1]
    return float(kept)


def verdict_of(low: float, high: float, target: float) -> str:
    """A realised rate's interval ``[low, high]`` beside its ``target``: ``above`` (the whole
    interval exceeds it), ``below`` (it is under), or ``consistent`` (it holds the target: more
    episodes would tell)."""
    return "above" if low > target else "below" if high < target else "consistent"


@dataclass(frozen=True)
class Stretches:
    """Long ID episodes (validation's ``max_steps``, or a logged run's: replay) cut into stretches
    as long as the threshold's calibration episodes were on average: the per-episode bound is for
    episodes like those, so a stretch is what it speaks of in a longer run. Each episode gives
    ``max(1, T // length)`` stretches of its T steps, the last taking the steps left over (so none
    is shorter than a calibration episode, or than the episode); a stretch is alarmed where an alarm
    was raised in it.

    Attributes:
        length: steps of a stretch (the calibration episodes' mean length).
        total, alarmed: stretches, and those in which an alarm was raised.
        low, high: the 95% interval of the alarmed share with each episode's stretches counted as
            a cluster (:func:`~oodmon.monitor.threshold.clustered_interval`): the stretches of one
            episode alarm together more often than independent ones would.
        design_effect: how much the episodes' clustering widened it (1: not at all).
    """

    length: int
    total: int
    alarmed: int
    low: float
    high: float
    design_effect: float = 1.0

    @property
    def rate(self) -> float:
        return self.alarmed / self.total

    @classmethod
    def of(cls, episodes: Sequence[tuple[int, Sequence[int]]], length: int) -> Stretches:
        """The stretches of ``episodes``, each ``(steps, the steps where alarms were raised)``.

        Example:
            >>> s = Stretches.of([(1000, [3]), (1250, [999, 1100]), (300, [])], 500)
            >>> s.total, s.alarmed
            (5, 2)
        """
        sums = ClusterSums()
        for steps, alarms in episodes:
            sums.add(*cls.count(steps, alarms, length))
        return cls.of_sums(sums, length)

    @staticmethod
    def count(steps: int, alarms: Sequence[int], length: int) -> tuple[int, int]:
        """One episode's ``(stretches alarmed, stretches)``: its ``steps`` cut into stretches of
        ``length``, alarms raised at the steps ``alarms``.

        Example:
            >>> Stretches.count(1250, [999, 1100], 500)
            (1, 2)
        """
        stretches = max(1, steps // length)
        return len({min(step // length, stretches - 1) for step in alarms}), stretches

    @classmethod
    def of_sums(cls, sums: ClusterSums, length: int) -> Stretches:
        """The stretches of episodes counted one by one (:meth:`count`) into ``sums``."""
        interval = sums.interval()
        return cls(length, interval.trials, interval.successes, interval.low, interval.high, interval.design_effect)


#: Up to this many statistics :func:`conformal_rank` reads the CDF at every k; beyond, it bisects,
#: which needs no array of n numbers (``calibrate --episodes 10**30`` asked numpy for one, and its
#: "Maximum allowed size exceeded" came as a traceback).
_EVERY_K = 1_000_000


def _smallest_k(n: int, p: float, confidence: float) -> int:
    """The smallest k in [0, n) with P(Binomial(n, p) <= k) >= ``confidence``; n where there is none.

    Example:
        >>> _smallest_k(200, 0.95, 0.9), _smallest_k(44, 0.95, 0.9), _smallest_k(10**30, 0.95, 0.9) > 0.95 * 10**30
        (194, 44, True)
    """
    if n <= _EVERY_K:
        ok = np.nonzero(_binomial_cdf(np.arange(n), n, p) >= confidence)[0]
        return int(ok[0]) if len(ok) else n
    low, high = 0, n  # the CDF rises with k; at k = n it is 1, which any confidence < 1 reaches
    while low < high:
        middle = (low + high) // 2
        if _binomial_cdf(middle, n, p) >= confidence:
            high = middle
        else:
            low = middle + 1
    return low


def _binomial_cdf(k: np.ndarray, n: int, p: float) -> np.ndarray:
    """P(Binomial(n, p) <= k) for whole k in [0, n]: the kernel ``scipy.stats.binom.cdf`` calls
    (Boost's), to the bit, without importing ``scipy.stats``, which took 0.6-0.7 s of the start of
    every command that calibrates, validates or benches (2026-12-04); ``scipy.stats`` itself where
    a SciPy keeps that kernel elsewhere. The public ``scipy.special.bdtr`` (Cephes) and ``betainc``
    round otherwise in the last bits, and a threshold's rank turns on ties (``p = 0.5``)."""
    try:
        from scipy.special._ufuncs import _binom_cdf
    except ImportError:  # pragma: no cover  (another SciPy)
        from scipy.stats import binom

        return binom.cdf(k, n, p)
    return _binom_cdf(np.asarray(k, dtype=np.float64), np.float64(n), p)  # (n as the kernel takes it: 10**30 too)


class OutlyingThresholdWarning(UserWarning):
    """:func:`calibrate`: the threshold lies far above the calibration episode statistic below it
    (:data:`OUTLYING`), so that one ID episode the detector could not model sets it alone."""


#: How many times farther from the calibration episodes' median statistic than the statistic just
#: below it a threshold is said to be set by one outlying episode. Measured on ID statistics (3,000
#: draws each of 22, 45, 50 and 90 of them, `results/calibration/`): at most 35 (CartPole's
#: `features`; `combined` 18, `dynamics` 6.6, Pong's `frames` 7.1); a LunarLander PPO's one ID
#: touch-down, 2e9 (2026-11-29, before the dynamics model took jumping readings as inputs only).
OUTLYING = 1000.0


class EarlyPeaksWarning(UserWarning):
    """:func:`calibrate`: the calibration episodes' highest scores come in their first steps, and a
    warm-up (:data:`WARMUP_HINT` steps) would set a much lower threshold (:data:`EARLY_GAIN`)."""


#: The warm-up :func:`calibrate` tries when it has none: the learned detectors' window (their score
#: is a mean over the last 20 transitions, over fewer until 20 have come since the reset).
WARMUP_HINT = 20
#: :class:`EarlyPeaksWarning` comes when that warm-up leaves the threshold at most this share of its
#: height above the ID steps' median score. The figure it names was chosen by the warning (it comes
#: when that figure is low), so it does not keep the threshold's promise: the warning says to
#: calibrate the warm-up on other episodes. The shipped Pendulum ensemble's `dynamics`
#: (`scripts/early_peaks_selection.py`, 2026-11-29): of 4,000 calibrations of 50 drawn from 600 ID
#: episodes, 2.8% warn, and 80% of those would give a warm-up threshold above 5% false alarms on
#: the other 550 (7.8% of all draws, within the promise's 10%). Measured on the first 50 (90) of 200 ID episodes of the
#: monitor's bench at far 0.05, confidence 0.9 (0.99): docs/your-policy.md's PPO hopper (`Hopper-v5`,
#: `combined` of `dynamics` alone) 0.56 (0.56), thresholds 4.28 and 2.61 (4.29 and 2.62), with
#: `drift` too 0.72 (its bench's calibration); another hopper of ours (six runs of 50,000 steps,
#: `dynamics` alone) 0.56 (0.49); the shipped CartPole agents'
#: `combined` ensemble 1.0 (0.64), Dropout 0.89 (0.89), DropConnect 1.0 (1.0); Pendulum's `dynamics`
#: DropConnect 0.77 (0.70), Dropout 1.0, ensemble 0.92. All of these with detectors fitted before
#: fitting version 6, whose ``dynamics`` standardises its means over the first transitions after a
#: reset: with the zoo's Pendulum ensemble refitted so, none of the 4,000 calibrations warns.
EARLY_GAIN = 2 / 3


def _warn_if_early(episodes: list[np.ndarray], values: np.ndarray, value: float, rank: int, median: float,
                   detector: str, consecutive: int, window: int) -> None:
    """Warn when the episode statistics ``values`` of the consecutive rule (the threshold ``value``
    their ``rank``-th), taken from step :data:`WARMUP_HINT` on, would give a threshold much lower
    (:data:`EARLY_GAIN`) above the steps' ``median`` score."""
    if not episodes or min(len(s) for s in episodes) < 2 * WARMUP_HINT + consecutive + window:
        return  # short episodes: a warm-up would take much of them
    late = np.array([episode_statistic(s, consecutive, window, warmup=WARMUP_HINT) for s in episodes])
    would = float(np.sort(late)[rank - 1])
    if not (math.isfinite(value) and math.isfinite(would)) or value <= median:
        return
    if (would - median) <= EARLY_GAIN * (value - median):
        # a learned detector's means cover few transitions there; the policy's spread has no mean and
        # may peak there all the same (the Pendulum Dropout bench's trials: 44 and 45 of 45 episodes)
        why = "" if detector == "spread" else ", where a learned detector's mean covers few transitions since the reset"
        warnings.warn(EarlyPeaksWarning(
            f"{int(np.sum(late < values))} of the {len(episodes)} calibration episodes reach their highest {detector} "
            f"score only within their first {WARMUP_HINT} steps{why}: from step {WARMUP_HINT} "
            f"on, these episodes would set the threshold at "
            f"{would:.4g} instead of {value:.4g} (the ID steps' median score {median:.4g}). That figure does not keep "
            f"the promise (this warning comes when it is low): for a warm-up, calibrate on other ID episodes "
            f"(`--warmup {WARMUP_HINT} --seed S`, S past these episodes' seeds; in Python calibrate_agent(..., "
            f"warmup={WARMUP_HINT}, seed=S)) and `oodmon validate` it; no alarm then in an episode's first "
            f"{WARMUP_HINT} steps but for a NaN reading"), stacklevel=3)


def _episode_arrays(episode_scores: Any) -> list[np.ndarray]:
    """``episode_scores`` as float64 arrays, one per episode.

    Raises:
        InvalidParameterError: text, or an episode's scores that are not a 1-D array of numbers.
    """
    def refuse(what: str) -> InvalidParameterError:
        return InvalidParameterError(f"episode_scores is not allowed: {what}; give one 1-D array of per-step scores "
                                     "per ID episode")

    if isinstance(episode_scores, (str, bytes)):
        raise refuse("text")
    episodes = []
    for i, scores in enumerate(episode_scores):
        try:
            episode = np.asarray(scores, dtype=np.float64)
        except (TypeError, ValueError):
            raise refuse(f"episode {i}'s scores are no numbers ({scores!r:.40})") from None
        if episode.ndim != 1:
            raise refuse(f"episode {i}'s scores have shape {episode.shape}")
        episodes.append(episode)
    return episodes


def _warn_if_outlying(ordered: np.ndarray, rank: int, detector: str) -> None:
    """Warn when the ``rank``-th of the sorted episode statistics ``ordered`` (the threshold) is an
    outlier (:data:`OUTLYING`)."""
    finite = ordered[np.isfinite(ordered)]  # a NaN-scored episode's +inf: out of the median
    if len(finite) < 4 or rank < 2:
        return
    value, median, below = float(ordered[rank - 1]), float(np.median(finite)), float(ordered[rank - 2])
    if math.isfinite(below) and below > median and (value - median) / (below - median) > OUTLYING:
        warnings.warn(OutlyingThresholdWarning(
            f"the {detector} threshold {value:.4g} lies {(value - median) / (below - median):.3g} times as far above "
            f"the {len(ordered)} calibration episodes' median statistic ({median:.4g}) as the statistic below it "
            f"({below:.4g}): one ID episode the detector could not model sets it, and the alarm will miss whatever "
            "scores less. The false-alarm promise holds; to watch, find that episode's steps (`oodmon run` in the ID "
            "env with --mcap, `oodmon replay --plots`), fit the detectors on more episodes (--fit-episodes), or "
            "watch with another detector"), stacklevel=3)


@dataclass(frozen=True)
class Threshold:
    """A calibrated threshold and how it was made.

    Attributes:
        value: the threshold on the score.
        score: the spread score's name (see ``scores``); the score the alarm reads when
            ``detector`` is ``spread``.
        consecutive: m of the alarm rule.
        mode: ``"episode"`` (guarantee per episode) or ``"step"``.
        far: the target false-alarm rate (per episode, or per step in step mode).
        n_episodes: ID calibration episodes.
        n_steps: ID calibration steps.
        quantiles: quantiles (and max) of the ID per-step scores, for orientation; under a
            sequential rule also the median and the largest of its statistic per calibration
            episode (``statistic_q50``, ``statistic_max``; since 2026-12-07), the threshold's scale.
        task, method: the agent it was calibrated for.
        window: the rule compares the mean of the last ``window`` scores (1: each score).
        policy_hash: ``sha256:...`` of the weights it was calibrated on (``None``: not recorded).
        detector: the detector whose score the alarm reads (``spread``, ``dynamics``,
            ``features``, ``combined``); files written before detectors existed read as ``spread``.
        confidence: the probability, over the calibration episodes, that this threshold's
            false-alarm rate is at most ``far`` (``None``: at most ``far`` on average over
            calibrations only; files written before it existed).
        rank: the threshold is the ``rank``-th smallest of the ``n_episodes`` calibration statistics
            (``None``: not recorded).
        rule: ``consecutive`` (m steps in a row, with ``window``), ``cusum`` or ``martingale``
            (see ``sequential``); files written before it existed read as ``consecutive``.
        reference: a sequential rule's ID reference scores, pooled or by time since reset
            (:meth:`~oodmon.monitor.sequential.Reference.to_dict`), from episodes apart from the
            calibration ones; ``None`` for ``consecutive``.
        masks: the MC masks of the policy it was calibrated on, ``sampled`` or ``fixed`` (the
            spread of fixed sub-networks is another score's scale); ``None``: not an MC policy,
            or not recorded.
        warmup: the rule looks at no finite score of an episode's first ``warmup`` steps (see
            ``alarms``); files written before it existed read as 0.
        detectors_hash: ``sha256:...`` of the fitted detector the alarm reads, and of the learned
            ones it combines (:meth:`~oodmon.monitor.detectors.DetectorSet.fingerprint`): the
            monitor refuses other fitted detectors, whose scores are on another scale. ``None``:
            ``spread``, or not recorded (files written before it existed).
        samples: the samples per decision of the policy it was calibrated on (an MC agent's K, an
            ensemble's members): the spread's scale, and an MC policy's mean decision, are K's (a
            CartPole DropConnect threshold of K=20, 0 of 100 fresh ID episodes alarmed, read 6 of 100
            with K=5). ``None``: a policy without samples, or not recorded (files written before it
            existed).
        episode_seeds: the reset seeds of the ID episodes it was calibrated on, by use, each as
            ``[first, end)``: ``calibration``, and ``reference`` for a sequential rule; ``oodmon
            validate`` refuses to count false alarms on them (they are not fresh: the threshold is
            the largest statistic of its calibration episodes, or near it). ``None``: not recorded
            (files written before 2026-12-01, or a threshold calibrated on scores alone).
        workers: the processes its episodes were played in (:mod:`oodmon.side_by_side`): an MC
            agent's samples drew from one stream in one process, and from a stream per episode
            in two or more. ``None``: not recorded.
        obs_noise: the sensor noise of the ID world it was calibrated in (oodmon's CartPole and
            Pendulum envs' ``obs_noise``, a fraction of each reading's ID spread): ``oodmon
            validate`` and ``oodmon run`` play that world unless told otherwise. ``None``: not
            recorded (files written before 2026-12-05, or calibrated on scores alone); read as 0.
        max_steps: the time limit of its calibration episodes, where calibration set one instead of
            the env's own (``oodmon calibrate --max-steps``: a deployment's runs are longer than the
            env's episodes); ``oodmon validate`` plays episodes that long unless told otherwise.
            ``None``: the env's own limit.
        longest_episode: the steps of its longest calibration episode: the :class:`Monitor` warns
            when an episode runs past it, where the bound no longer speaks (``None``: not recorded,
            files written before 2026-12-05).
        logs: the logs whose ID episodes it was calibrated on (``oodmon recalibrate``,
            :func:`oodmon.replay.calibrate_from_logs`), each ``{"path", "run_id", "episodes"}``;
            ``None``: calibrated on episodes it played.
        models: the SB3 model files of the policy it was calibrated on, in their order (the first
            acts), each ``{"path", "sha256"}`` (the file's bytes): where other models are refused,
            the monitor says which these were (the same in another order, some of them).
            ``None``: not models from files, or not recorded (files written before 2026-12-07).
        sb3: what else that SB3 policy was loaded with, as ``--env``, ``--vec-normalize``,
            ``--frame-stack`` and ``--mean`` give it (:func:`sb3_loading`): ``{"env_id",
            "vec_normalize", "frame_stack", "mean"}``, the statistics' file and the stack's depth
            ``None`` where it had none. ``oodmon run`` and ``validate`` given the threshold alone
            load that policy again from :attr:`models` and these (before, they asked for ``--sb3
            ... --env ...`` again). ``None``: not models from files (the statistics in memory
            too), or not recorded (files written before 2026-12-07).
        reading_names: the name of each number of the observations the detectors read, by index,
            as ``oodmon calibrate --reading-names`` gave them (a robot's ``["knee angle", ...]``),
            or as the logs it was calibrated on kept them: a :class:`Monitor` with this threshold
            names its alarms' readings by them unless given others. ``None``: none given (an env
            whose layout oodmon knows, or a dict observation's keys, are named without).
        episode_hashes: of a threshold calibrated on recorded episodes
            (:func:`~oodmon.monitor.recorded.calibrate_on_episodes`), the hash of each
            (:func:`~oodmon.monitor.recorded.episode_hash`), which
            :func:`~oodmon.monitor.recorded.validate_on_episodes` refuses to count again (they are
            not fresh). ``None``: calibrated on episodes it played, or on logs.
    """

    value: float
    score: str
    consecutive: int
    mode: str
    far: float
    n_episodes: int
    n_steps: int
    quantiles: dict[str, float] = field(default_factory=dict)
    task: str | None = None
    method: str | None = None
    window: int = 1
    policy_hash: str | None = None
    detector: str = "spread"
    confidence: float | None = None
    rank: int | None = None
    rule: str = "consecutive"
    reference: dict[str, Any] | None = field(default=None, repr=False)
    masks: str | None = None
    warmup: int = 0
    detectors_hash: str | None = None
    samples: int | None = None
    episode_seeds: dict[str, list[int]] | None = None
    workers: int | None = None
    obs_noise: float | None = None
    max_steps: int | None = None
    longest_episode: int | None = None
    logs: list[dict[str, Any]] | None = None
    models: list[dict[str, str]] | None = None
    sb3: dict[str, Any] | None = None
    reading_names: list[str] | None = None
    episode_hashes: list[str] | None = None

    def __post_init__(self) -> None:
        _check_fields(self)

    @property
    def rule_text(self) -> str:
        """The rule in words, with this threshold's value."""
        value = self.value + 0.0  # (-0.0, all ID scores 0 and negated, reads 0)
        return rule_text(f"{value:.6g}", self.consecutive, self.window, self.rule, self.warmup)

    def reference_scores(self) -> Reference | None:
        """The sequential rule's :class:`~oodmon.monitor.sequential.Reference` (``None``: consecutive)."""
        return None if self.reference is None else Reference.from_dict(self.reference)

    @property
    def promise(self) -> str:
        """What holds for a fresh ID episode, in words."""
        unit = "episode" if self.mode == "episode" else "step (approximately: a large-sample limit of the steps)"
        if self.confidence is None:
            return f"a fresh ID {unit} alarms with probability at most {self.far:g}, on average over calibrations"
        return (f"with probability >= {self.confidence:g} over its {self.n_episodes} calibration episodes, this "
                f"threshold's false-alarm rate per {unit} is <= {self.far:g}")

    @property
    def covered_steps(self) -> int | None:
        """The steps of an episode its bound speaks for: its longest calibration episode's, in
        episode mode (``None``: a bound on steps, or a file that records none). An episode longer
        is warned of by the :class:`Monitor` and noted by ``oodmon run`` and replay."""
        return self.longest_episode if self.mode == "episode" else None

    @property
    def sb3_files(self) -> str | None:
        """Its SB3 model files (:attr:`models`) as ``--sb3`` takes them, quoted for a shell; ``None``
        where not recorded."""
        return sb3_arguments(self.models) if self.models else None

    @property
    def mean_episode(self) -> int | None:
        """A calibration episode's steps on average, in episode mode (``None``: a bound on steps):
        the stretches ``validate --max-steps`` and replay cut longer ID episodes into
        (:class:`Stretches`), as what the per-episode bound speaks of."""
        if self.mode != "episode" or not self.n_episodes:
            return None
        return max(1, round(self.n_steps / self.n_episodes))

    @property
    def calibration_noise(self) -> float:
        """The sensor noise of the world the bound is for: :attr:`obs_noise`, 0 where not recorded."""
        return self.obs_noise or 0.0

    @property
    def step_mode_warning(self) -> str | None:
        """What to warn of before alarms are raised with this threshold (``oodmon run``,
        ``watch(threshold=...)``): calibrated per step, it bounds the share of ID steps above it, not
        of episodes, so nearly every ID episode alarms at some step (2026-12-05: 20 of 20 CartPole ID
        episodes, 6 to 39 alarms each, with no word of why). ``None``: calibrated per episode."""
        if self.mode != "step":
            return None
        return (f"this threshold was calibrated per step (mode 'step'): it bounds the share of ID steps above it "
                f"({self.far:g}), not of episodes, so most ID episodes will alarm at some step; for alarms, "
                "calibrate per episode (the default, without --mode step)")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self) | {"rule_text": self.rule_text}

    def save(self, path: str | Path) -> Path:
        """Write the threshold file (JSON)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json(path, self.to_dict())
        return path

    @classmethod
    def load(cls, path: str | Path) -> Threshold:
        """Read a threshold file written by :meth:`save` (``oodmon calibrate``).

        Raises:
            ConfigError: the file is missing, not JSON, not a threshold file, or has a field whose
                value is not allowed (every field is checked: a ``NaN`` value would silence every
                alarm, ``consecutive: 0`` is no rule).
        """
        path = Path(path)
        data = read_json(path, name="threshold file", missing="make one with `oodmon calibrate`",
                         folder="give the JSON file `oodmon calibrate` wrote")
        if not isinstance(data, dict):
            raise ConfigError(f"{path} is not a threshold file: it holds {type(data).__name__} {data!r:.40}, "
                              "not an object with value, score, consecutive, ...")
        names = [f for f in cls.__dataclass_fields__]
        if "rule_text" not in data:  # written before sequential rules: "rule" held the rule in words
            data.pop("rule", None)
        unknown = [k for k in data if k not in names and k != "rule_text"]
        if unknown:  # a newer oodmon's field could change the rule: say so rather than drop it in silence
            warnings.warn(f"threshold file {path} has fields this oodmon does not know, which it ignores: "
                          f"{', '.join(map(str, unknown))} (written by a newer oodmon? its alarm rule may differ here)",
                          UserWarning, stacklevel=2)
        missing = [n for n in ("value", "score", "consecutive", "mode", "far", "n_episodes", "n_steps") if n not in data]
        if missing:
            raise ConfigError(f"{path} is not a threshold file: it lacks {', '.join(missing)}")
        try:
            return cls(**{k: v for k, v in data.items() if k in names})
        except ConfigError as error:
            raise type(error)(f"threshold file {path}: {error}") from None

    def check_matches(self, *, task: str | None, method: str | None, score: str, policy_hash: str | None,
                      masks: str | None = None, samples: int | None = None,
                      aliases: Sequence[str] = ()) -> list[str]:
        """How this threshold differs from the policy and score it is about to be used with: one
        line per difference (empty: it matches). A field not recorded on either side is not compared;
        ``aliases``: other hashes of the same weights that fit as well (``policy_hash_aliases``).

        Example:
            >>> Threshold(1.0, "chosen_std", 3, "episode", 0.05, 20, 100, task="cartpole").check_matches(
            ...     task="pong", method=None, score="chosen_std", policy_hash=None)
            ["it was calibrated for task 'cartpole', not 'pong'"]
        """
        found = []
        for name, mine, theirs in (("task", self.task, task), ("method", self.method, method),
                                   ("score", self.score, score), ("masks", self.masks, masks)):
            if mine is not None and theirs is not None and mine != theirs:
                found.append(f"it was calibrated for {name} {mine!r}, not {theirs!r}")
        if self.samples is not None and samples is not None and self.samples != samples:
            found.append(f"it was calibrated with {self.samples} samples per decision, and this policy draws {samples}: "
                         "the spread's scale, and an MC policy's mean decision, are those of its samples")
        if other_weights(self.policy_hash, policy_hash, aliases):
            if _named_alike(self.policy_hash, policy_hash):  # a plain policy without weights, edited since
                found.append(f"it was calibrated for another version of {policy_hash.split()[0][5:]}: its code, or a "
                             f"value it reads, has changed since ({self.policy_hash}, this is {policy_hash})")
            elif "name:" in (self.policy_hash[:5], policy_hash[:5]):  # a plain policy without weights (agents.plain)
                found.append(f"it was calibrated for another policy ({self.policy_hash}, this is {policy_hash})")
            else:
                found.append(f"it was calibrated on other weights ({self.policy_hash[:19]}..., these are "
                             f"{policy_hash[:19]}...; an SB3 model's VecNormalize statistics count as its weights)")
        return found


def _named_alike(recorded: str, current: str) -> bool:
    """Two hashes of plain policies of one name (``name:act code:...``,
    :func:`oodmon.agents.plain.plain_policy_hash`)."""
    return recorded.startswith("name:") and current.startswith("name:") and recorded.split()[0] == current.split()[0]


def _check_fields(threshold: Threshold) -> None:
    """Every field of a threshold has a value the monitor can use, or :class:`InvalidParameterError`."""
    from oodmon.monitor.scores import SCORES

    def bad(name: str, allowed: str) -> InvalidParameterError:
        return InvalidParameterError(f"{name}={getattr(threshold, name)!r} is not allowed; {allowed}")

    def is_number(value: object) -> bool:
        return isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)

    if not is_number(threshold.value) or not math.isfinite(threshold.value):
        raise bad("value", "the threshold must be a finite number (NaN would silence every alarm)")
    if threshold.score not in SCORES:
        raise bad("score", f"choose one of {', '.join(SCORES)}")
    if threshold.detector not in DETECTOR_NAMES:
        raise bad("detector", f"choose one of {', '.join(DETECTOR_NAMES)}")
    check_consecutive(threshold.consecutive)
    check_window(threshold.window)
    if threshold.rule in RULES:
        check_warmup(threshold.warmup, threshold.rule)
    if threshold.mode not in MODES:
        raise bad("mode", "use 'episode' or 'step'")
    if threshold.rule not in RULES:
        raise bad("rule", f"choose one of {', '.join(RULES)}")
    if threshold.rule != "consecutive":
        if threshold.reference is None:
            raise bad("reference", f"the {threshold.rule} rule needs its reference of ID scores")
        threshold.reference_scores()  # a damaged reference fails here, when the file is read
    _check_far_and_confidence(threshold.far, threshold.confidence)
    if threshold.rank is not None and not is_whole(threshold.rank):
        raise bad("rank", "it must be a whole number >= 1, or null")
    for name in ("n_episodes", "n_steps"):
        if not is_whole(getattr(threshold, name), minimum=0):
            raise bad(name, "it must be a whole number >= 0")
    for name in ("task", "method", "policy_hash", "detectors_hash"):
        if getattr(threshold, name) is not None and not isinstance(getattr(threshold, name), str):
            raise bad(name, "it must be a string or null")
    if not isinstance(threshold.quantiles, dict):
        raise bad("quantiles", "it must be an object of numbers")
    if threshold.samples is not None and not is_whole(threshold.samples):
        raise bad("samples", "it must be a whole number >= 1, or null")
    if threshold.masks is not None and threshold.masks not in MASKS:
        raise bad("masks", f"use {', '.join(map(repr, MASKS))} or null")
    if threshold.workers is not None and not is_whole(threshold.workers):
        raise bad("workers", "it must be a whole number >= 1, or null")
    if threshold.obs_noise is not None:
        check_obs_noise("a threshold file", threshold.obs_noise)  # the envs' own bounds
    if threshold.max_steps is not None and not is_whole(threshold.max_steps):
        raise bad("max_steps", "it must be a whole number >= 1 of steps, or null (the env's own time limit)")
    if threshold.longest_episode is not None and not is_whole(threshold.longest_episode, minimum=0):
        raise bad("longest_episode", "it must be a whole number >= 0 of steps, or null")
    seeds = threshold.episode_seeds
    if seeds is not None and not (isinstance(seeds, dict) and all(
            isinstance(name, str) and isinstance(pair, (list, tuple)) and len(pair) == 2
            and all(is_whole(seed, minimum=0) for seed in pair) and pair[0] <= pair[1] for name, pair in seeds.items())):
        raise bad("episode_seeds", "it must be an object of [first, end) seed pairs by use, or null")
    logs = threshold.logs
    if logs is not None and not (isinstance(logs, list) and all(
            isinstance(log, dict) and isinstance(log.get("path"), str) and is_whole(log.get("episodes"), minimum=0)
            for log in logs)):
        raise bad("logs", "it must be a list of the logs it was calibrated on ({path, run_id, episodes}), or null")
    models = threshold.models
    if models is not None and not (isinstance(models, list) and all(
            isinstance(model, dict) and isinstance(model.get("path"), str) and isinstance(model.get("sha256"), str)
            for model in models)):
        raise bad("models", "it must be a list of the model files it was calibrated on ({path, sha256}), or null")
    loaded = threshold.sb3
    if loaded is not None and not (
            isinstance(loaded, dict) and set(loaded) == {"env_id", "vec_normalize", "frame_stack", "mean"}
            and isinstance(loaded["env_id"], str) and loaded["env_id"]
            and (loaded["vec_normalize"] is None or isinstance(loaded["vec_normalize"], str))
            and (loaded["frame_stack"] is None or is_whole(loaded["frame_stack"]))
            and isinstance(loaded["mean"], bool)):
        raise bad("sb3", "it must be an object of what its SB3 models were loaded with ({env_id, vec_normalize, "
                         "frame_stack, mean}), or null")
    names = threshold.reading_names
    if names is not None and not (isinstance(names, list) and names and all(isinstance(name, str) for name in names)):
        raise bad("reading_names", "it must be a list of texts, the name of each number of the observations by "
                                   "index, or null")
    hashes = threshold.episode_hashes
    if hashes is not None and not (isinstance(hashes, list) and all(isinstance(text, str) for text in hashes)):
        raise bad("episode_hashes", "it must be a list of the hashes of the recorded episodes it was calibrated on, "
                                    "or null")


def model_files(models: object) -> list[dict[str, str]] | None:
    """:attr:`Threshold.models` of a policy's SB3 models as an agent's metadata (``models``) and a
    log's ``about.models`` record them (each a dict with at least ``path`` and ``sha256``): each
    ``{"path", "sha256"}``, in order; ``None`` where there are none, one is in memory, or the record
    is not of that form.

    Example:
        >>> model_files([{"path": "a.zip", "sha256": "ab", "algorithm": "DQN"}])
        [{'path': 'a.zip', 'sha256': 'ab'}]
        >>> model_files([{"path": "(in memory)", "sha256": "ab"}]) is None, model_files(None) is None
        (True, True)
    """
    if not isinstance(models, list) or not models or not all(
            isinstance(m, dict) and isinstance(m.get("path"), str) and isinstance(m.get("sha256"), str)
            and m["sha256"] and m["path"] != "(in memory)" for m in models):
        return None
    return [{"path": m["path"], "sha256": m["sha256"]} for m in models]


def sb3_loading(metadata: Mapping[str, Any]) -> dict[str, Any] | None:
    """:attr:`Threshold.sb3` of a policy of SB3 models loaded from files, from what its agent's
    metadata (:func:`oodmon.agents.sb3.load_sb3`) or its log's ``about`` (each value as text, the
    records as JSON) says of it: the env id, the VecNormalize statistics' file, the VecFrameStack
    depth and whether the ensemble's mean acts. ``None`` where its models are not files
    (:func:`model_files`), its statistics were in memory, a record is not of that form, or it
    does not say which model acts (a log written before 2026-12-07: the mean or the first model).

    Example:
        >>> sb3_loading({"models": [{"path": "a.zip", "sha256": "ab"}], "env_id": "CartPole-v1",
        ...              "frame_stack": 4, "deployed": "a.zip (the first model)"})
        {'env_id': 'CartPole-v1', 'vec_normalize': None, 'frame_stack': 4, 'mean': False}
        >>> sb3_loading({"models": '[{"path": "a.zip", "sha256": "ab"}]', "env_id": "Pendulum-v1",
        ...              "vec_normalize": '{"path": "vn.pkl", "sha256": "cd"}', "deployed": "ensemble mean"})
        {'env_id': 'Pendulum-v1', 'vec_normalize': 'vn.pkl', 'frame_stack': None, 'mean': True}
        >>> sb3_loading({"models": '[{"path": "a.zip", "sha256": "ab"}]', "env_id": "Pendulum-v1"}) is None
        True
    """
    def record(key: str) -> Any:  # an agent's metadata holds the records, a log's about their JSON
        value = metadata.get(key)
        try:
            return json.loads(value) if isinstance(value, str) else value
        except ValueError:
            return None

    env_id, normalizer, depth = metadata.get("env_id"), record("vec_normalize"), record("frame_stack")
    if model_files(record("models")) is None or not isinstance(env_id, str) or not env_id \
            or not isinstance(metadata.get("deployed"), str):
        return None
    path = normalizer.get("path") if isinstance(normalizer, dict) else None
    if (normalizer is not None and (not isinstance(path, str) or path == "(in memory)")) \
            or (depth is not None and not is_whole(depth)):
        return None
    return {"env_id": env_id, "vec_normalize": path, "frame_stack": depth,
            "mean": metadata.get("deployed") == "ensemble mean"}


def recorded_sb3(threshold: Threshold, path: str | Path, *, vec_normalize: Any = None, frame_stack: int | None = None,
                 mean: bool = False) -> tuple[dict[str, Any], list[str]]:
    """How to load the SB3 models ``threshold`` (read from ``path``) was calibrated on again
    (:attr:`Threshold.models`, :attr:`Threshold.sb3`): ``{"models", "env_id", "vec_normalize",
    "frame_stack", "mean"}``, where ``vec_normalize`` and ``frame_stack`` given replace the
    recorded ones and ``mean`` given or recorded deploys the mean; each file where it was, else
    the file of its name beside ``path`` (the two moved together; a model there only of the
    recorded bytes). With it, ``gone``: the recorded paths found in neither place (``models``
    keeps those as recorded). The policy's hash, which the monitor checks, decides whether the
    files found are the weights it was calibrated on. ``oodmon run``/``validate`` and
    :func:`oodmon.watch` given the threshold alone load them so; ``--import`` and
    ``--unsafe-load-pickles`` are never read from a file (they run code)."""
    from oodmon.hashing import file_sha256

    beside, recorded = Path(path).parent, threshold.sb3 or {}

    def found(was: str, sha256: str | None = None) -> str | None:  # where the file at ``was`` is now
        if Path(was).is_file():
            return was
        moved = beside / Path(was).name
        return str(moved) if moved.is_file() and (sha256 is None or file_sha256(moved) == sha256) else None

    files = threshold.models or []
    models = [found(model["path"], model["sha256"]) for model in files]
    gone = [model["path"] for model, at in zip(files, models) if at is None]
    statistics = recorded.get("vec_normalize")
    if vec_normalize is None and statistics is not None:  # (given: the recorded one is not looked for)
        vec_normalize = found(statistics)
        if vec_normalize is None:
            gone.append(statistics)
    return {"models": [at or model["path"] for model, at in zip(files, models)], "env_id": recorded.get("env_id"),
            "vec_normalize": vec_normalize,
            "frame_stack": recorded.get("frame_stack") if frame_stack is None else frame_stack,
            "mean": bool(mean or recorded.get("mean"))}, gone


def sb3_arguments(models: Sequence[dict[str, str]]) -> str:
    """SB3 model files (:func:`model_files`) as ``--sb3`` takes them, each path quoted for a shell.

    Example:
        >>> sb3_arguments([{"path": "runs/a.zip", "sha256": "ab"}, {"path": "my b.zip", "sha256": "cd"}])
        "runs/a.zip 'my b.zip'"
    """
    return " ".join(shlex.quote(model["path"]) for model in models)


def calibrate(
    episode_scores: Sequence[np.ndarray],
    far: float = 0.05,
    *,
    consecutive: int = DEFAULT_CONSECUTIVE,
    mode: str = "episode",
    score: str = "chosen_std",
    task: str | None = None,
    method: str | None = None,
    window: int = 1,
    policy_hash: str | None = None,
    detector: str = "spread",
    confidence: float | None = DEFAULT_CONFIDENCE,
    rule: str = "consecutive",
    reference: Reference | None = None,
    masks: str | None = None,
    warmup: int = 0,
    detectors_hash: str | None = None,
    samples: int | None = None,
    above: int = 0,
) -> Threshold:
    """Calibrate a threshold on the per-step scores of held-out ID episodes.

    Args:
        episode_scores: one array of per-step scores per ID episode.
        far: target false-alarm rate, 0 < far < 1.
        consecutive: m of the alarm rule (episode mode; step mode uses 1).
        mode: ``"episode"`` or ``"step"`` (see the module docstring).
        window: the rule's averaging window in steps (episode mode; step mode uses 1).
        detector: the detector whose scores these are.
        confidence: 1 - d, the probability over the calibration episodes that the threshold's
            false-alarm rate is at most ``far`` (``None``: on average over calibrations only).
        rule: ``consecutive``, ``cusum`` or ``martingale`` (episode mode).
        reference: a sequential rule's ID scores by time since reset, from other ID episodes than
            ``episode_scores`` (see ``sequential``).
        masks: the MC masks of the policy the scores are of (see :class:`Threshold`).
        warmup: the rule looks at no finite score of an episode's first ``warmup`` steps
            (episode mode, the consecutive rule).
        detectors_hash: the fingerprint of the fitted detector whose scores these are (see
            :class:`Threshold`).
        samples: the samples per decision of the policy the scores are of (see :class:`Threshold`).
        above: further calibration episodes (episode mode) whose statistics are known to lie
            above any threshold, or whose scores are not all known (a log's episode an alarm may
            have cut short: :func:`oodmon.replay.calibrate_from_logs`); counted as +inf, which can
            only raise the threshold, so its bound holds.

    Raises:
        InvalidParameterError: ``far`` or ``confidence`` outside (0, 1), an unknown mode, a bad
            ``consecutive`` or ``window``, ``episode_scores`` that are not 1-D arrays of numbers.
        ConfigError: too few episodes for ``far`` at ``confidence`` (the message says how many).

    Example:
        >>> rng = np.random.default_rng(0)
        >>> thr = calibrate([rng.random(100) for _ in range(45)], far=0.05, consecutive=1)
        >>> thr.n_episodes, thr.rank, round(thr.value, 3)
        (45, 45, 1.0)
    """
    _check_far_and_confidence(far, confidence)
    if mode not in MODES:
        raise InvalidParameterError(f"mode={mode!r} is not allowed; use 'episode' or 'step'")
    if rule not in RULES:
        raise InvalidParameterError(f"rule={rule!r} is not allowed; choose one of {', '.join(RULES)}")
    if rule != "consecutive" and mode != "episode":
        raise InvalidParameterError(f"the {rule} rule is calibrated per episode; use mode='episode'")
    consecutive = check_consecutive(consecutive) if mode == "episode" else 1
    window = check_window(window) if mode == "episode" else 1
    warmup = check_warmup(warmup, rule)
    if warmup and mode != "episode":
        raise InvalidParameterError("a warm-up is calibrated per episode; use mode='episode'")
    episodes = _episode_arrays(episode_scores)
    if not is_whole(above, minimum=0):
        raise InvalidParameterError(f"above={above!r} is not allowed; give a whole number >= 0 of episodes")
    if above and mode != "episode":
        raise InvalidParameterError("episodes whose scores are not all known (above=) are counted per episode; use "
                                    "mode='episode'")
    if mode == "episode":
        values = np.array([episode_statistic(s, consecutive, window, rule=rule, reference=reference, warmup=warmup)
                           for s in episodes] + [math.inf] * above)
        unit = "episodes"
    else:
        values = np.concatenate(episodes) if episodes else np.array([])
        unit = "steps"
    ordered = np.sort(values)
    if mode == "step" and confidence is not None:
        value = step_threshold(episodes, far, confidence)
        rank = int(np.searchsorted(ordered, value, side="right"))
    else:
        rank = conformal_rank(len(values), far, confidence, unit=unit)
        value = float(ordered[rank - 1])
    if not math.isfinite(value) and above and rank > len(values) - above:
        raise ConfigError(f"the calibration gives no threshold: its rank {rank} of {len(values)} episodes falls among "
                          f"the {above} whose scores are not all known (an alarm may have cut them short); give "
                          f"more ID episodes, or a larger far")
    if value == math.inf:  # (it said the episodes were too short for the rule)
        infinite = int(np.sum(values == math.inf))
        raise ConfigError(
            f"the calibration gives threshold inf (never alarm): {infinite} of its {len(values)} calibration {unit} "
            f"scored +inf, at or above its rank {rank}: a reading that is not finite (NaN or infinite: a failed "
            "sensor, which the monitor counts as the most shifted) in ID; calibrate on ID episodes whose readings "
            "are finite, or with a larger far")
    if not math.isfinite(value):
        shortest = min((len(s) for s in episodes), default=0)
        raise ConfigError(
            f"the calibration gives threshold {value} (always or never alarm): the rule needs "
            f"{warmup + consecutive + window - 1} steps per episode (consecutive={consecutive}, window={window}"
            + (f", warmup={warmup}" if warmup else "") + f") and the shortest calibration episode has {shortest}; "
            "use a smaller window" + (" or warm-up" if warmup else "") + " or longer episodes"
        )
    steps = np.concatenate(episodes) if episodes else np.array([0.0])
    quantiles = {f"q{int(q * 100)}": float(np.quantile(steps, q)) for q in _QUANTILES} | {"max": float(steps.max())}
    if rule != "consecutive" and mode == "episode":  # its statistic is on a scale of its own: said beside the threshold
        quantiles |= {"statistic_q50": float(np.quantile(ordered, 0.5)), "statistic_max": float(ordered[-1])}
    if mode == "episode":
        _warn_if_outlying(ordered, rank, detector)
        if rule == "consecutive" and not warmup and not above:  # (episodes cut short: no late statistics)
            _warn_if_early(episodes, values, value, rank, quantiles["q50"], detector, consecutive, window)
    return Threshold(value, score, consecutive, mode, float(far), len(values) if mode == "episode" else len(episodes),
                     int(sum(len(s) for s in episodes)),
                     quantiles, task, method, window, policy_hash, detector,
                     None if confidence is None else float(confidence), rank, rule,
                     None if reference is None else reference.to_dict(), masks, warmup, detectors_hash,
                     None if samples is None else int(samples),
                     longest_episode=max((len(s) for s in episodes), default=0))
