"""The alarm rule and the alarms it raises.

An alarm is raised when the score stays above the threshold for ``consecutive`` steps in a row
(m). The default m = 3 trades two steps of delay for robustness: MC and ensemble scores are noisy
step to step, and a single noisy step should not page anyone. The calibration's false-alarm
guarantee holds for any m, because it is computed for the rule as a whole (see ``threshold``).

With ``window`` w > 1 the rule looks at the mean of the last w scores instead of the score
itself (and only once w steps of the episode are scored). That is for scores that separate ID
from OOD steps well on average but spike now and then in long ID episodes: on Pong a 3000-step
ID game always has a few high steps, so an m = 3 rule calibrated on them sits above most steps
of a corrupted game; the mean over 100 steps does not (see docs/pong.md). The
price is a delay of at least w steps.

With ``warmup`` N > 0 the rule looks at no finite score of an episode's first N steps: the
learned detectors' scores there are means over the few transitions since the reset, which may be
rare ones (a hopper dropping onto the ground from its start pose), and an episode's highest ID
score often comes there, so it sets the threshold for the whole episode. Measured on docs/pong.md's
PPO hopper (``Hopper-v5``, 200 ID episodes of its bench, ``combined`` of ``dynamics`` alone):
122 of 200 peaked within their first 20 steps (65 at step 2); each episode's highest score from
step 20 on had a 99th percentile of 2.62 against 4.27 over the whole episode (with ``drift`` in
``combined`` too, 71 of 200 and 3.25 against 4.28). A NaN or +inf score
(a failed sensor) alarms in the warm-up too. The price: no alarm in the first N steps of an episode.

The sequential rules (``rule="cusum"`` or ``"martingale"``, see ``sequential``) instead
accumulate evidence over steps from each score's p-value against the scores of ID reference
episodes; they need a :class:`~oodmon.monitor.sequential.Reference` and ignore m and the window.
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from oodmon.envs.readings import reading_label
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.sequential import Reference, SequentialStatistic, sequential_path
from oodmon.validation import MOST_STEPS, is_step_count

__all__ = [
    "DEFAULT_CONSECUTIVE", "AlarmEvent", "AlarmTracker", "Region", "check_consecutive", "check_warmup", "check_window",
    "compared_name", "default_consecutive", "readings_text",
    "episode_statistic",
    "rule_text", "rule_window", "trailing_mean",
]

DEFAULT_CONSECUTIVE = 3


def default_consecutive(detector: str) -> int:
    """m of the alarm rule when none is given: 3 for the ``spread`` detector, whose MC and ensemble
    scores are noisy step to step; 1 for the learned detectors, whose scores are already means over
    the last 20 transitions, so that m = 3 only adds two steps of delay. Measured with the monitor's
    benchmark (random onsets, the shipped agents, docs/bench.md): m = 1 alarms before the failure in
    100% of failing Pendulum episodes against 75-84% with m = 3 (Pendulum with l = 0.05 falls two
    steps after the onset), at the same false-alarm bound.

    Example:
        >>> default_consecutive("spread"), default_consecutive("dynamics")
        (3, 1)
    """
    return DEFAULT_CONSECUTIVE if detector == "spread" else 1


#: The alarm window per task where it is not 1: Pong's spread and features scores are compared as
#: means over 200 decisions.
DEFAULT_WINDOW = {"pong": 200}


def default_window(task: str | None, detector: str | None = None) -> int:
    """The alarm rule's window when none is given: 1 (each step's score) for CartPole and Pendulum,
    whose learned detectors already average their last 20 transitions, and for the ``frames``
    detector, whose 20-step means already separate every corrupted Pong frame from every ID one,
    the ``stillness`` and ``motion`` detectors, whose runs are their own memory, ``vanishing``, whose
    count of the episode's events is, and ``combined`` (Pong's default: of frames and
    stillness); 200 for Pong's spread and features, whose distances vary frame to frame while a
    corruption persists. Measured with the monitor's benchmark on the shipped Pong agents
    (results/monitor/README.md): features with window 1 alarmed 52/90 (Dropout) and 80/90
    (ensemble) shifted games; with 200, 90/90 and 90/90, median delays 66 and 81 decisions.

    Example:
        >>> default_window("pong"), default_window("pong", "combined"), default_window("cartpole"), default_window(None)
        (200, 1, 1, 1)
    """
    if detector in ("frames", "stillness", "motion", "vanishing", "combined"):
        return 1
    return DEFAULT_WINDOW.get(task or "", 1)


def _needs(reference: Reference | None, rule: str) -> Reference:
    if reference is None:
        raise ConfigError(f"the {rule} rule needs a reference of ID scores (calibrate it: oodmon calibrate --rule {rule})")
    return reference


def check_consecutive(consecutive: object) -> int:
    """``consecutive`` as an int from 1 to :data:`~oodmon.validation.MOST_STEPS`, or :class:`InvalidParameterError`."""
    if not is_step_count(consecutive):
        raise InvalidParameterError(
            f"consecutive={consecutive!r} is not allowed; the alarm rule needs an integer from 1 to {MOST_STEPS:,} of "
            "steps in a row"
        )
    return int(consecutive)


def check_window(window: object) -> int:
    """``window`` as an int from 1 to :data:`~oodmon.validation.MOST_STEPS`, or :class:`InvalidParameterError`."""
    if not is_step_count(window):
        raise InvalidParameterError(
            f"window={window!r} is not allowed; the alarm rule averages the scores of an integer from 1 to "
            f"{MOST_STEPS:,} of last steps"
        )
    return int(window)


def check_warmup(warmup: object, rule: str = "consecutive") -> int:
    """``warmup`` as an int from 0 to :data:`~oodmon.validation.MOST_STEPS`, or :class:`InvalidParameterError`;
    a sequential rule takes none (:class:`ConfigError`: it weighs each step against ID steps at the
    same time since reset already)."""
    if not is_step_count(warmup, minimum=0):
        raise InvalidParameterError(
            f"warmup={warmup!r} is not allowed; the alarm rule skips an integer from 0 to {MOST_STEPS:,} of first steps "
            "of each episode"
        )
    if warmup and rule != "consecutive":
        raise ConfigError(f"the {rule} rule takes no warm-up: it weighs each step against ID steps at the same time "
                          "since reset already")
    return int(warmup)


def rule_text(threshold: str, consecutive: int, window: int = 1, rule: str = "consecutive", warmup: int = 0) -> str:
    """The rule in words, e.g. ``"mean score over 100 steps > 0.05 for 3 consecutive steps"``.

    Example:
        >>> rule_text("2.3", 1, warmup=20)
        'score > 2.3 from step 20 of each episode'
    """
    if rule == "cusum":
        return f"CUSUM of -log10(p) - 1 > {threshold} (p: the score against ID reference steps)"
    if rule == "martingale":
        return f"log10 of the conformal test martingale > {threshold} (p: the score against ID reference steps)"
    what = "score" if window == 1 else f"mean score over {window} steps"
    text = f"{what} > {threshold}" if consecutive == 1 else f"{what} > {threshold} for {consecutive} consecutive steps"
    return text + (f" from step {warmup} of each episode" if warmup else "")


def rule_window(text: str) -> tuple[int, int]:
    """The window and the warm-up of a rule in words as :func:`rule_text` writes it (a log's
    ``rule``): 1 and 0 where it says none.

    Example:
        >>> rule_window("mean score over 200 steps > threshold"), rule_window("score > threshold")
        ((200, 0), (1, 0))
        >>> rule_window("mean score over 5 steps > threshold for 3 consecutive steps from step 20 of each episode")
        (5, 20)
    """
    window = re.match(r"mean score over (\d+) steps > ", text)
    warmup = re.search(r" from step (\d+) of each episode$", text)
    return int(window.group(1)) if window else 1, int(warmup.group(1)) if warmup else 0


def compared_name(text: str) -> str | None:
    """What a rule in words as :func:`rule_text` writes it (a log's ``rule``) compares with the
    threshold where that is not each step's score: a window's mean, a CUSUM or a martingale's
    statistic (which :attr:`AlarmTracker.compared` holds at each step, and the sinks log beside
    the score); ``None`` for a rule that compares each step's score.

    Example:
        >>> compared_name("mean score over 200 steps > 0.5"), compared_name("score > 0.5 for 3 consecutive steps")
        ('mean over 200 steps', None)
        >>> compared_name(rule_text("threshold", 1, rule="cusum"))
        'CUSUM'
    """
    window = rule_window(text)[0]
    if window > 1:
        return f"mean over {window} steps"
    if text.startswith("CUSUM of "):
        return "CUSUM"
    if text.startswith("log10 of the conformal test martingale "):
        return "log10 martingale"
    return None


def trailing_mean(scores: np.ndarray, window: int) -> np.ndarray:
    """The mean of each run of ``window`` scores, one per step from step ``window - 1`` on.

    Example:
        >>> trailing_mean(np.array([1.0, 3.0, 2.0, 6.0]), 2)
        array([2. , 2.5, 4. ])
    """
    scores = np.asarray(scores, dtype=np.float64)
    if np.isnan(scores).any():  # a score that could not be computed counts as the most shifted, as in AlarmTracker
        scores = np.where(np.isnan(scores), np.inf, scores)
    if window == 1:
        return scores
    if len(scores) < window:
        return scores[:0]
    with np.errstate(invalid="ignore"):  # +inf and -inf in one window: NaN, said by the callers, not numpy
        return sliding_window_view(scores, window).mean(axis=1)


def episode_statistic(scores: np.ndarray, consecutive: int, window: int = 1, *, rule: str = "consecutive",
                      reference: Reference | None = None, warmup: int = 0) -> float:
    """The largest t such that the (``window``-step mean) scores stay >= t for ``consecutive`` steps in a row.

    An episode raises an alarm under threshold ``thr`` exactly when this statistic exceeds
    ``thr``, so calibrating on it calibrates the whole rule. ``-inf`` for an episode too short
    for the rule to look at (fewer than ``warmup + window + consecutive - 1`` steps). ``warmup``:
    the rule looks at the scores from that step on (a NaN or +inf score before it: ``inf``, as
    :class:`AlarmTracker` alarms on it). A sequential rule's statistic is the largest value its path
    takes (see ``sequential``; ``reference`` needed).

    Example:
        >>> episode_statistic(np.array([0.1, 0.9, 0.8, 0.2, 0.7]), 2)
        0.8
        >>> episode_statistic(np.array([1.0, 3.0, 2.0, 6.0]), 1, window=2)  # the means are 2, 2.5, 4
        4.0
        >>> episode_statistic(np.array([9.0, 3.0, 2.0, 6.0]), 1, warmup=1)  # step 0 is the warm-up's
        6.0
    """
    if rule != "consecutive":
        path = sequential_path(rule, _needs(reference, rule), scores)
        return float(path.max()) if len(path) else float("-inf")
    if warmup:
        early = np.asarray(scores[:warmup], dtype=np.float64)
        if np.any(np.isnan(early) | (early == np.inf)):  # a failed sensor alarms in the warm-up too
            return float("inf")
        scores = scores[warmup:]
    values = trailing_mean(scores, window)
    if len(values) < consecutive:
        return float("-inf")
    # A window holding +inf and -inf means NaN, which AlarmTracker finds above no threshold: so does the
    # statistic (numpy's min and max would carry the NaN to it, and the calibration refused it)
    values = np.where(np.isnan(values), -np.inf, values)
    return float(sliding_window_view(values, consecutive).min(axis=1).max())


class Region(NamedTuple):
    """A part of the picture a detector reads, in its pixels: rows ``top`` to ``top + height - 1``
    and columns ``left`` to ``left + width - 1`` of a picture of ``rows`` x ``columns``
    (:attr:`AlarmEvent.region`).

    Example:
        >>> Region(28, 21, 14, 14, 84, 84).text()
        'rows 28-41, columns 21-34 of the 84x84 picture'
    """

    top: int
    left: int
    height: int
    width: int
    rows: int
    columns: int

    def text(self) -> str:
        """The region in words."""
        return (f"rows {self.top}-{self.top + self.height - 1}, columns {self.left}-{self.left + self.width - 1} of "
                f"the {self.rows}x{self.columns} picture")


@dataclass(frozen=True)
class AlarmEvent:
    """An alarm: the score stayed above the threshold for ``consecutive`` steps.

    Attributes:
        episode: the episode's index in the run.
        step: the step at which the rule fired (the last of the consecutive steps).
        score: the value the rule compared at that step: the score, with a window the mean
            of the last ``window`` scores, with a sequential rule its statistic.
        threshold: the threshold in force.
        rule: the rule, e.g. ``"score > threshold for 3 consecutive steps"``.
        cause: what raised the score at that step, for whoever answers the alarm (the
            :class:`~oodmon.monitor.Monitor` sets it): the alarm's detector (``dynamics``), or for
            ``combined`` the member ranked highest among its ID scores there (``stillness``: the
            camera stands still; ``dynamics (mean since the episode began)``: a shift too slight for
            single steps); ``a reading that is not finite`` for a NaN or infinite observation.
            Empty where nothing says (an :class:`AlarmTracker` on its own).
        readings: the readings whose change at that step the dynamics model predicted worst, as
            (flattened index, standardised residual: the change's distance from the model's
            prediction in its predicted standard deviations, signed), the larger first, at most
            two, each at least 3 off (the :class:`~oodmon.monitor.Monitor` sets them where its
            detectors hold a fitted ``dynamics`` model): which sensor to look at, a stuck one or
            the reading a changed physics moves first. Empty where none is that far off (no
            ``dynamics`` detector, the episode's first step, a reading that is not finite). Where
            the ``drift`` detector raised the alarm and no step's reading is that far off, its own
            reading: the residuals summed over its last ``readings_steps`` steps, over their root.
        readings_steps: the steps the residuals of ``readings`` cover: 1, the alarm's step; more,
            the drift detector's window.
        reading_names: the names of ``readings``, in their order, where the env's layout is known
            (:func:`~oodmon.envs.readings.reading_names`: ``pole angle``); empty otherwise.
        region: where in the picture, for a picture policy's alarm raised by the ``vanishing``
            detector (alone or as ``combined``'s leader): the tiles where things vanished or
            appeared in the episode where they never did in its ID fitting episodes, their bounding
            box in the pixels of the picture it reads
            (:meth:`~oodmon.monitor.detectors.VanishingDetector.where`): of a frozen part of the
            camera, its border, where the ball goes in and comes out. ``None`` otherwise.
    """

    episode: int
    step: int
    score: float
    threshold: float
    rule: str
    cause: str = ""
    readings: tuple[tuple[int, float], ...] = ()
    readings_steps: int = 1
    reading_names: tuple[str, ...] = ()
    region: Region | None = None

    def text(self) -> str:
        """One line for a person: where, the value against the threshold (named by the rule: the
        score, a window's mean, a sequential statistic; :func:`compared_name`), the rule and the cause.

        Example:
            >>> AlarmEvent(0, 41, 7.25, 4.5, "score > threshold", "dynamics").text()
            'episode 0 step 41: score 7.25 > 4.5 (score > threshold); cause: dynamics'
            >>> AlarmEvent(0, 90, 2.5, 2.0, "mean score over 50 steps > threshold").text()
            'episode 0 step 90: mean over 50 steps 2.5 > 2 (mean score over 50 steps > threshold)'
            >>> AlarmEvent(0, 51, 9.5, 5.9, "score > threshold", "dynamics", ((3, 293.7),)).text().split("; ")[-1]
            "reading [3] off the dynamics model's prediction by +294 sd"
            >>> AlarmEvent(0, 51, 9.5, 5.9, "score > threshold", "dynamics", ((1, -311.3), (3, 310.8))).text()[-73:]
            "readings [1] and [3] off the dynamics model's prediction by -311, +311 sd"
        """
        cause = f"; cause: {self.cause}" if self.cause else ""
        value = compared_name(self.rule) or "score"
        where = f"; where: {self.region.text()}" if self.region is not None else ""
        return (f"episode {self.episode} step {self.step}: {value} {self.score:.4g} > {self.threshold:.4g} "
                f"({self.rule}){cause}{readings_text(self.readings, self.readings_steps, self.reading_names)}{where}")


def readings_text(readings: Sequence[tuple[int, float]], steps: int = 1, names: Sequence[str] = ()) -> str:
    """:attr:`AlarmEvent.readings` in words, after a ``"; "``, each named where ``names`` (in their
    order) says; empty where there are none.

    Example:
        >>> readings_text([(4, 4.51)], steps=20)
        "; reading [4] drifting from the dynamics model's predictions: +4.51 sd summed over its last 20 steps"
        >>> readings_text([(2, -269.0)], names=["pole angle"])
        "; reading [2] (pole angle) off the dynamics model's prediction by -269 sd"
    """
    if not readings:
        return ""
    named = list(names) + [""] * (len(readings) - len(names))
    indices = " and ".join(reading_label(index, name) for (index, _), name in zip(readings, named))
    values = ", ".join(f"{residual:+.3g}" for _, residual in readings)
    plural = "s" if len(readings) > 1 else ""
    if steps > 1:
        return (f"; reading{plural} {indices} drifting from the dynamics model's predictions: {values} sd summed over "
                f"{'their' if plural else 'its'} last {steps} steps")
    return f"; reading{plural} {indices} off the dynamics model's prediction by {values} sd"


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

    def __init__(self, threshold: float, consecutive: int = DEFAULT_CONSECUTIVE, window: int = 1, *,
                 rule: str = "consecutive", reference: Reference | None = None, warmup: int = 0) -> None:
        self.threshold = float(threshold)
        self.consecutive = check_consecutive(consecutive)
        self.window = check_window(window)
        self.warmup = check_warmup(warmup, rule)
        self.rule = rule_text("threshold", self.consecutive, self.window, rule, self.warmup)
        self._sequential = None if rule == "consecutive" else SequentialStatistic(rule, _needs(reference, rule))
        self.reset()

    def reset(self) -> None:
        """Start a new episode."""
        self._run = 0
        self._recent: deque[float] = deque(maxlen=self.window)
        #: What the rule compared with the threshold at the last step where that is not the score
        #: (:func:`compared_name`): the window's mean (NaN until the window fills after the
        #: warm-up), a sequential rule's statistic; NaN under a rule that compares each score.
        #: What the sinks log beside the score (Rerun's ``/compared``, MCAP's ``compared``).
        self.compared = math.nan
        self._holding = False
        if self._sequential is not None:
            self._sequential.reset()

    def update(self, episode: int, step: int, score: float) -> tuple[bool, AlarmEvent | None]:
        if score != score:  # NaN: a score that could not be computed counts as the most shifted
            score = math.inf
        if step < self.warmup:  # the warm-up: the rule looks at no finite score, nor keeps one
            holds = score == math.inf
            rising, self._holding = holds and not self._holding, holds
            return holds, AlarmEvent(episode, step, score, self.threshold, self.rule) if rising else None
        if self._sequential is not None:
            value = self.compared = self._sequential.update(step, score)
            holds, rising = value > self.threshold, value > self.threshold and not self._holding
            self._holding = holds
            return holds, AlarmEvent(episode, step, value, self.threshold, self.rule) if rising else None
        if self.window > 1:
            self._recent.append(float(score))
            if len(self._recent) < self.window:
                return False, None
            # Summed afresh (w additions) rather than as a running sum, which drifts over
            # thousands of steps; equal to trailing_mean up to rounding.
            score = self.compared = sum(self._recent) / self.window
        self._run = self._run + 1 if score > self.threshold else 0
        if self._run < self.consecutive:
            return False, None
        event = AlarmEvent(episode, step, float(score), self.threshold, self.rule) if self._run == self.consecutive else None
        return True, event
