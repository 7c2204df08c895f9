"""Thresholds calibrated on in-distribution episodes only, with a false-alarm guarantee.

Episode mode (the default): each held-out ID calibration episode gives one number, the
:func:`~oodmon.monitor.alarms.episode_statistic` of its scores under the alarm rule; an episode
alarms exactly when that number exceeds the threshold. With n calibration episodes and a target
false-alarm rate a, split conformal prediction takes the ceil((n + 1)(1 - a))-th smallest of
them: for a fresh ID episode exchangeable with the calibration episodes, the probability that it
raises any alarm is at most a. This needs n >= 1/a - 1 episodes (19 for a = 0.05).

With a ``window`` (see ``alarms``) the statistic is taken over the trailing means of the scores;
the guarantee is the same, for that rule.

Step mode: the same quantile over all per-step scores (rule m = 1, no window). Steps of one episode are
correlated, so its per-step rate is only approximately a; it is there for comparison with the
paper, which scores steps.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.alarms import DEFAULT_CONSECUTIVE, check_consecutive, check_window, episode_statistic, rule_text

__all__ = ["MODES", "Threshold", "calibrate"]

MODES = ("episode", "step")
#: The detectors a threshold may name (``oodmon.monitor.detectors.DETECTORS``; spelled here so
#: that reading a threshold file does not import them).
DETECTOR_NAMES = ("spread", "dynamics", "features", "combined")
_QUANTILES = (0.5, 0.9, 0.95, 0.99)


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
        quantiles: quantiles (and max) of the ID per-step scores, for orientation.
        task, method: the agent it was calibrated for.
        window: the rule compares the mean of the last ``window`` scores (1: each score).
        policy_hash: ``sha256:...`` of the weights it was calibrated on (``None``: not recorded).
        detector: the detector whose score the alarm reads (``spread``, ``dynamics``,
            ``features``, ``combined``); files written before detectors existed read as ``spread``.
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

    def __post_init__(self) -> None:
        _check_fields(self)

    @property
    def rule(self) -> str:
        return rule_text(f"{self.value:.6g}", self.consecutive, self.window)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self) | {"rule": self.rule}

    def save(self, path: str | Path) -> Path:
        """Write the threshold file (JSON)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
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
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise ConfigError(f"threshold file {path} does not exist; make one with `oodmon calibrate`") from None
        except IsADirectoryError:
            raise ConfigError(f"threshold file {path} is a folder; give the JSON file `oodmon calibrate` wrote") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise ConfigError(f"threshold file {path} is not valid JSON ({error})") from None
        if not isinstance(data, dict):
            raise ConfigError(f"{path} is not a threshold file: it holds {type(data).__name__} {data!r:.40}, "
                              "not an object with value, score, consecutive, ...")
        names = [f for f in cls.__dataclass_fields__]
        missing = [n for n in ("value", "score", "consecutive", "mode", "far", "n_episodes", "n_steps") if n not in data]
        if missing:
            raise ConfigError(f"{path} is not a threshold file: it lacks {', '.join(missing)}")
        try:
            return cls(**{k: v for k, v in data.items() if k in names})
        except ConfigError as error:
            raise type(error)(f"threshold file {path}: {error}") from None

    def check_matches(self, *, task: str | None, method: str | None, score: str, policy_hash: str | None) -> list[str]:
        """How this threshold differs from the policy and score it is about to be used with: one
        line per difference (empty: it matches). A field not recorded on either side is not compared.

        Example:
            >>> Threshold(1.0, "chosen_std", 3, "episode", 0.05, 20, 100, task="cartpole").check_matches(
            ...     task="pong", method=None, score="chosen_std", policy_hash=None)
            ["it was calibrated for task 'cartpole', not 'pong'"]
        """
        found = []
        for name, mine, theirs in (("task", self.task, task), ("method", self.method, method),
                                   ("score", self.score, score)):
            if mine is not None and theirs is not None and mine != theirs:
                found.append(f"it was calibrated for {name} {mine!r}, not {theirs!r}")
        if self.policy_hash and policy_hash and policy_hash != "unknown" and self.policy_hash != policy_hash:
            found.append(f"it was calibrated on other weights ({self.policy_hash[:19]}..., these are {policy_hash[:19]}...)")
        return found


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
    if threshold.mode not in MODES:
        raise bad("mode", "use 'episode' or 'step'")
    if not is_number(threshold.far) or not 0.0 < threshold.far < 1.0:
        raise bad("far", "the target false-alarm rate must satisfy 0 < far < 1")
    for name in ("n_episodes", "n_steps"):
        value = getattr(threshold, name)
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 0:
            raise bad(name, "it must be a whole number >= 0")
    for name in ("task", "method", "policy_hash"):
        if getattr(threshold, name) is not None and not isinstance(getattr(threshold, name), str):
            raise bad(name, "it must be a string or null")
    if not isinstance(threshold.quantiles, dict):
        raise bad("quantiles", "it must be an object of numbers")


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
) -> Threshold:
    """Calibrate a threshold on the per-step scores of held-out ID episodes.

    Args:
        episode_scores: one array of per-step scores per ID episode.
        far: target false-alarm rate, 0 < far < 1.
        consecutive: m of the alarm rule (episode mode; step mode uses 1).
        mode: ``"episode"`` or ``"step"`` (see the module docstring).
        window: the rule's averaging window in steps (episode mode; step mode uses 1).
        detector: the detector whose scores these are.

    Raises:
        InvalidParameterError: ``far`` outside (0, 1), an unknown mode, a bad ``consecutive`` or ``window``.
        ConfigError: too few episodes for the guarantee at this ``far``.

    Example:
        >>> rng = np.random.default_rng(0)
        >>> thr = calibrate([rng.random(100) for _ in range(39)], far=0.05, consecutive=1)
        >>> thr.n_episodes, round(thr.value, 3)
        (39, 1.0)
    """
    if not (isinstance(far, (int, float)) and 0.0 < far < 1.0):
        raise InvalidParameterError(f"far={far!r} is not allowed; the target false-alarm rate must satisfy 0 < far < 1")
    if mode not in MODES:
        raise InvalidParameterError(f"mode={mode!r} is not allowed; use 'episode' or 'step'")
    consecutive = check_consecutive(consecutive) if mode == "episode" else 1
    window = check_window(window) if mode == "episode" else 1
    episodes = [np.asarray(s, dtype=np.float64) for s in episode_scores]
    if mode == "episode":
        values = np.array([episode_statistic(s, consecutive, window) for s in episodes])
        unit = "episodes"
    else:
        values = np.concatenate(episodes) if episodes else np.array([])
        unit = "steps"
    n = len(values)
    rank = math.ceil((n + 1) * (1 - far))
    if rank > n:
        raise ConfigError(
            f"far={far} needs at least {math.ceil(1 / far - 1)} ID calibration {unit} for its guarantee; got {n}"
        )
    value = float(np.sort(values)[rank - 1])
    if not math.isfinite(value):
        shortest = min((len(s) for s in episodes), default=0)
        raise ConfigError(
            f"the calibration gives threshold {value} (always or never alarm): the rule needs "
            f"{consecutive + window - 1} steps per episode (consecutive={consecutive}, window={window}) and the "
            f"shortest calibration episode has {shortest}; use a smaller window or longer episodes"
        )
    steps = np.concatenate(episodes) if episodes else np.array([0.0])
    quantiles = {f"q{int(q * 100)}": float(np.quantile(steps, q)) for q in _QUANTILES} | {"max": float(steps.max())}
    return Threshold(value, score, consecutive, mode, float(far), len(episodes), int(sum(len(s) for s in episodes)),
                     quantiles, task, method, window, policy_hash, detector)
