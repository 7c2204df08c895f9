"""``combined``: one score from several detectors, each read as its rank among ID scores.

No single detector wins everywhere (dynamics sees changed physics, the spread sees Pendulum's
``max_speed``, features see corrupted frames), and their scores live on unrelated scales. Each
member's score ``s`` becomes its conformal p-value against that member's scores at held-out ID
steps, ``p = (1 + #{ID scores >= s}) / (n + 1)``, and the combined score is the largest
``-log10 p`` over members (the smallest p-value: what Bonferroni's rule looks at). Beyond the
largest ID score every p-value is the same ``1 / (n + 1)``; there the rank grows on by the
excess over that maximum in units of the member's ID standard deviation, so that a far larger
excursion still ranks higher.

For ``dynamics`` (:data:`LONG_MEMBERS`) it ranks one more statistic: the member's mean score since
the episode began (over its last ``horizon`` steps at most), against the same mean along held-out ID
episodes. A shift the agent copes with can leave each transition only a little surprising, too
little for the member's 20-step mean to stand out, while its mean over hundreds of steps does.
Measured on the shipped agents (``scripts/combined_long_mean.py``: 10 ID episodes against 5 of each
variant where the agent fails, per-step AUROC; detectors fitted on 30 ID episodes, as then):
CartPole DropConnect's lowest over its 44 variants rose from 0.776 to 0.983 (``gravity=19.6``,
doubled gravity, which the agent mostly survives; a 100-step mean gave 0.850), CartPole Dropout's
from 0.983 to 0.998, Pendulum DropConnect's, Dropout's and ensemble's from 0.946, 0.963 and 0.978 to
0.965, 0.969 and 0.986; the CartPole ensemble's moved from 0.992 to 0.991. The same mean of
``features`` and ``spread`` as well added nothing on CartPole and lowered Pendulum Dropout's lowest
to 0.922. The member's own score stays: it reacts within a few steps of a shift that comes
mid-episode, the long mean would not.

``features`` (:data:`LOG_MEMBERS`) is ranked by the logarithm of its score. Inside the ID scores'
range that changes no rank (the logarithm keeps their order); beyond the largest it measures the
excess as a ratio. The features detector's squared distances have a heavy ID tail: in one of 200 ID
episodes of the shipped CartPole ensemble they reached 48 ranks (about 45 ID standard deviations
past the held-out maximum) where every other member stayed below 7, and since the alarm's threshold
is the largest combined score of the calibration episodes, that one member set it (58.0) for all: a
dynamics detector far outside its ID range after a shift (9-171 ranks) alarmed 2 of 10 such
episodes. Ranked by its logarithm (the monitor's own benchmark, ``oodmon bench --protocol monitor
--task cartpole``, the same agents and episodes, detectors fitted on 30 ID episodes as then): the
ensemble's threshold fell to 6.33 and it alarmed 253 of 270 shifted episodes instead of 233 (gravity
x7-x10 from mid-episode: 23 of 40 instead of 3), 1 of 200 ID episodes (0 before), delays median /
p90 1 / 1 (1 / 3); Dropout's gravity delays fell from 4.5-18.5 to 1.5-3.5 steps at the median;
DropConnect's figures stayed the same; per-step AUROC moved by 0.0001 at most on CartPole.

``stillness`` (:data:`UNIT_MEMBERS`) counts its excess in steps (each step a sensor stands still
past the longest held-out run: one rank, a tenfold rarer p-value), not in ID standard deviations:
its ID scores are nearly all the same (Pong's newest frame stands still at under 1% of the steps),
their standard deviation tiny, so that a calibration episode whose camera stood still two steps
longer than any held-out one ranked some 20 higher and set the threshold for every member (a
random policy on 150-step Pong games, 2026-11-30: 45.1 where the other members' ID scores ranked
below 3). Measured on the monitor's benchmark of the shipped Pong DropConnect agent, its logged
scores ranked again (a combined of spread, features, frames and stillness, its threshold the
largest of 90 of the 200 ID games): a unit of 10 steps alarmed a frozen camera 53 steps after it
froze (median), 1 step 13; the corruptions' delays and the other ID games' alarms the same.

The alarm's threshold is calibrated on the combined score of its own ID episodes like any other
score, so its per-episode false-alarm guarantee is exact whatever the members' dependence.
"""

from __future__ import annotations

import math
from array import array
from bisect import bisect_left
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.detectors.base import Detector, RunningMean, StepContext
from oodmon.validation import is_whole

__all__ = ["DEFAULT_HORIZON", "LOG_MEMBERS", "LONG_MEMBERS", "UNIT_MEMBERS", "CombinedDetector"]

#: Members whose mean since the episode began the combined detector ranks too, by default.
LONG_MEMBERS = ("dynamics",)
#: The most recent steps that mean covers (CartPole's and Pendulum's whole episodes).
DEFAULT_HORIZON = 500
#: Members ranked by the logarithm of their score, by default (their scores are positive).
LOG_MEMBERS = ("features",)
#: Members whose excess beyond their largest ID score counts in this unit, not in ID standard
#: deviations: ``stillness``, whose value counts steps (see the module's text), and ``vanishing``,
#: which counts events (0 at nearly every ID step: each event past the held-out record, one rank).
UNIT_MEMBERS = {"stillness": 1.0, "vanishing": 1.0}
_LOG_FLOOR = 1e-300  # a score of 0 (never seen: a squared distance) is ranked as this
_log10 = math.log10


def _log(value: float) -> float:
    return math.log(value if value > _LOG_FLOOR else _LOG_FLOOR)


class CombinedDetector(Detector):
    """The largest ID rank (``-log10`` conformal p-value) of the member detectors' scores.

    Args:
        members: names of the detectors it combines; they are computed before it at each step.
        long_members: members whose mean since the episode began it ranks too (default: those of
            :data:`LONG_MEMBERS` among ``members``; ``[]`` for none).
        horizon: that mean covers the episode's last ``horizon`` steps at most.
        log_members: members ranked by the logarithm of their (positive) score (default: those of
            :data:`LOG_MEMBERS` among ``members``; ``[]`` for none).

    Example:
        >>> combined = CombinedDetector(["a", "b"]).fit_reference({"a": np.arange(99.0), "b": np.zeros(99)})
        >>> round(combined.score(StepContext(np.zeros(1), 0, scores={"a": 49.5, "b": 0.0})), 3)  # p = 50/100
        0.301
    """

    name = "combined"
    learned = True

    def __init__(self, members: Sequence[str], *, long_members: Sequence[str] | None = None,
                 horizon: int = DEFAULT_HORIZON, log_members: Sequence[str] | None = None) -> None:
        if not members or len(set(members)) != len(members) or "combined" in members:
            raise ConfigError(f"a combined detector needs distinct member detectors other than itself; got {members!r}")
        if long_members is None:
            long_members = [name for name in members if name in LONG_MEMBERS]
        if log_members is None:
            log_members = [name for name in members if name in LOG_MEMBERS]
        for label, chosen in (("long_members", long_members), ("log_members", log_members)):
            if len(set(chosen)) != len(chosen) or not set(chosen) <= set(members):
                raise ConfigError(f"{label} must be distinct members of the combined detector ({', '.join(members)}); "
                                  f"got {list(chosen)!r}")
        if not is_whole(horizon):
            raise InvalidParameterError(f"horizon={horizon!r} is not allowed; it must be an integer >= 1")
        self.members, self.long_members, self.horizon = list(members), list(long_members), horizon
        self.log_members = list(log_members)
        self._reference: dict[str, np.ndarray] | None = None
        self._scale: dict[str, float] = {}
        self._long_reference: dict[str, np.ndarray] = {}
        self._long_scale: dict[str, float] = {}
        self._means = {name: RunningMean(horizon) for name in self.long_members}
        #: What gave the last score: the member ranked highest (a long member's mean as
        #: ``"<name> (mean since the episode began)"``), or the first that could not score (NaN).
        self.leader: str | None = None

    @property
    def fitted(self) -> bool:
        return self._reference is not None

    def fit_reference(self, scores: Mapping[str, np.ndarray | Sequence[np.ndarray]]) -> CombinedDetector:
        """Take each member's scores at held-out ID steps (not the steps it was fitted on): one array
        of steps, or a list of per-episode arrays, which a long member needs (its mean since the
        episode began is computed along each).

        Raises:
            ConfigError: a member without scores, or with non-finite ones; a long member's scores
                not given per episode.
        """
        def episodes(name: str) -> list[np.ndarray]:
            given = scores.get(name, [])
            if isinstance(given, np.ndarray):  # the steps of one run, episodes not told apart
                return [given.reshape(-1)]
            return [np.asarray(values, np.float64).reshape(-1) for values in given]

        def sorted_reference(label: str, values: np.ndarray) -> np.ndarray:
            # float32, as saved: a loaded detector ranks exactly as the fitted one
            values = np.sort(values.astype(np.float32)).astype(np.float64)
            if len(values) < 2 or not np.all(np.isfinite(values)):
                raise ConfigError(f"the combined detector needs finite ID scores of {label} at two or more steps")
            return values

        def ranked_as(name: str, values: np.ndarray) -> np.ndarray:
            """What the member's scores are ranked as: their logarithm for a log member."""
            return np.log(np.maximum(values, _LOG_FLOOR)) if name in self.log_members else values

        reference, long_reference = {}, {}
        for name in self.members:
            per_episode = episodes(name)
            steps = np.concatenate(per_episode) if per_episode else np.zeros(0)
            if name in self.log_members and np.any(steps < 0):
                raise ConfigError(f"the combined detector ranks {name!r} by the logarithm of its score; its ID scores "
                                  "must not be negative")
            reference[name] = sorted_reference(repr(name), ranked_as(name, steps))
            if name in self.long_members:
                if isinstance(scores.get(name), np.ndarray):
                    raise ConfigError(f"give the ID scores of {name!r} per episode (a list of arrays): the combined "
                                      "detector ranks its mean since the episode began")
                means = np.concatenate([self._means[name].along(values) for values in per_episode])
                long_reference[name] = sorted_reference(f"{name!r}'s episode mean", ranked_as(name, means))
        scale = _scales(reference) | {name: unit for name, unit in UNIT_MEMBERS.items() if name in reference}
        self._set_reference(reference, scale, long_reference, _scales(long_reference))
        return self

    def _set_reference(self, reference: dict[str, np.ndarray], scale: dict[str, float],
                       long_reference: dict[str, np.ndarray], long_scale: dict[str, float]) -> None:
        self._reference, self._scale = reference, scale
        self._long_reference, self._long_scale = long_reference, long_scale
        # What score() reads for each member, in one tuple (no dict look-ups at a step but the
        # score's): the ID scores as contiguous doubles, their number, the largest ID score and
        # the scale of the excess beyond it. Until 2026-12-07 a list of floats, and beside it a list
        # of the rank of each of their n + 1 positions: some 0.9 MB a statistic of 15,000 ID steps
        # (the shipped CartPole ensemble's set 4.7 MB of Python objects, now 1.4), whose scattered
        # objects the search read from memory at each step: in the monitor's loop 6.9-7.5 us, now
        # 5.1-5.3 (benchmarks/detector_step.py), though in a warm cache bisect on the list took 0.18
        # us against 0.24 on the doubles (np.searchsorted of a scalar 1.1). The rank, computed at
        # the step, is the same float.
        self._by_name = {name: _ranked(reference[name], scale[name]) for name in self.members}
        self._long_by_name = {name: _ranked(long_reference[name], long_scale[name]) for name in self.long_members}
        # One entry per statistic ranked, the members' own scores first: (member, None, or for a
        # long member's mean its RunningMean, whether it is ranked by its logarithm, then as above,
        # then what the statistic is called as the leader)
        self._ranked = [(name, None, name in self.log_members, *self._by_name[name], name) for name in self.members] + \
            [(name, self._means[name], name in self.log_members, *self._long_by_name[name],
              f"{name} (mean since the episode began)") for name in self.long_members]

    def reset(self) -> None:
        for mean in self._means.values():
            mean.clear()

    def rank(self, name: str, value: float, *, long: bool = False) -> float:
        """``-log10`` of ``value``'s conformal p-value among the ID scores of member ``name`` (``long``:
        among its ID means since the episode began), grown beyond the largest by the excess in units
        of their standard deviation; for a log member all of it on the logarithm of ``value``."""
        values, n, top, scale = (self._long_by_name if long else self._by_name)[name]
        if name in self.log_members:
            value = _log(value)
        rank = -_log10((1 + n - bisect_left(values, value)) / (n + 1))
        return rank + (value - top) / scale if value > top else rank

    def score(self, context: StepContext) -> float:
        self.check_fitted()
        scores = context.scores
        best, leader = -math.inf, None
        try:
            # rank() of each statistic, written out in a plain loop: in the monitor's step this took
            # 6.3-6.5 us against 7.0-7.5 for max() over a list comprehension (benchmarks/detector_step.py)
            for name, mean, is_log, values, n, top, scale, label in self._ranked:
                value = scores[name] if mean is None else mean.add(scores[name])
                if value != value:  # NaN: a member that could not score (as a rank it would read 0, "most ID")
                    if best != math.inf:
                        best, leader = math.inf, label  # the most shifted; the loop goes on to feed the other means
                    continue
                if is_log:
                    value = _log(value)
                rank = -_log10((1 + n - bisect_left(values, value)) / (n + 1))
                if value > top:
                    rank += (value - top) / scale
                if rank > best:
                    best, leader = rank, label
            self.leader = leader
            return best
        except KeyError:
            missing = [m for m in self.members if m not in scores]
            if not missing:
                raise
            raise ConfigError(f"the combined detector needs the scores of {', '.join(missing)} at each step; the "
                              "monitor does not compute them") from None

    def config(self) -> dict[str, Any]:
        config: dict[str, Any] = {"members": self.members, "scale": self._scale}
        if self.long_members:  # absent: a file from before the long members, or none chosen
            config |= {"long_members": self.long_members, "horizon": self.horizon, "long_scale": self._long_scale}
        if self.log_members:  # absent: a file from before the log members, or none chosen
            config["log_members"] = self.log_members
        return config

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {**{f"reference.{name}": values.astype(np.float32) for name, values in self._reference.items()},
                **{f"long_reference.{name}": values.astype(np.float32) for name, values in self._long_reference.items()}}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> CombinedDetector:
        detector = cls(config["members"], long_members=config.get("long_members", []),
                       horizon=config.get("horizon", DEFAULT_HORIZON), log_members=config.get("log_members", []))
        try:
            reference = {name: np.asarray(tensors[f"reference.{name}"], np.float64) for name in detector.members}
            long_reference = {name: np.asarray(tensors[f"long_reference.{name}"], np.float64)
                              for name in detector.long_members}
        except KeyError as error:
            raise ConfigError(f"the combined detector's tensors lack the ID scores of {error}") from None
        scales = {kind: {name: float(config.get(kind, {}).get(name, 1.0)) for name in names}
                  for kind, names in (("scale", detector.members), ("long_scale", detector.long_members))}
        detector._set_reference(reference, scales["scale"], long_reference, scales["long_scale"])
        return detector


def _scales(reference: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Each reference's standard deviation (1 where it is 0): the unit of an excess beyond its maximum."""
    return {name: float(values.std()) or 1.0 for name, values in reference.items()}


def _ranked(reference: np.ndarray, scale: float) -> tuple[array, int, float, float]:
    """What score() reads for one statistic: the sorted ID values as contiguous doubles, their
    number, the largest and the scale of the excess beyond it."""
    values = array("d", reference.tolist())
    return values, len(values), values[-1], scale

