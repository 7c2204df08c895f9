"""A threshold, and detectors, fitted on the ID episodes of recorded logs: your deployment's own.

``oodmon calibrate`` plays ID episodes in a simulator. A deployment's own ID world often differs
from it (real sensors are noisier, a real cart heavier), and a threshold calibrated in the
simulator then alarms in much of the deployment's normal running: on 2026-12-06 the CartPole
ensemble's combined threshold, calibrated without sensor noise, alarmed 100 of 100 fresh ID
episodes with noise 0.01. Where no simulator plays the deployment's world, its own logs do: runs
of the deployed policy in a state known to be in distribution, logged by a :class:`Monitor`
(``oodmon run --mcap``, a ``MonitoredEnv`` with an ``McapSink``), hold every detector's score at
every step. :func:`calibrate_from_logs` calibrates the alarm on those scores with the same rule and
the same promise as ``oodmon calibrate``: the episodes are the calibration episodes, the logs' run
the deployed policy, detectors and world (all checked alike across the logs).

The detectors stay those that scored the logs, fitted in the simulator, on their scale. Where the
deployment's world is far from the simulator's, :func:`fit_detectors_from_logs` fits them on its
logs too (the observations and actions of each step); the alarm is then calibrated on other logs,
of runs scored by them (2026-12-06, the same noise: the simulator's fit recalibrated read
combined > 132,828 and caught a pole twice as long at delay median 65.5; fitted and calibrated on
the deployment's logs, > 6.04518 and delay 1).

Only whole ID episodes count: not a shifted one, nor one the run was stopped inside. An episode
that ended at the step an alarm began (the step a callback hears of it), without its env ending it,
may have been cut short by a callback that stops the episode: its scores after it are unknown, so
it counts as above any threshold (which can only raise the threshold; its promise holds).

The promise rests on the episodes to come being like the calibration episodes taken together
(exchangeable with them). Played episodes are, by their seeds; a deployment's logs need not be: its
world may drift while it is logged, or a shift nobody flagged may lie among its "ID" runs, and the
threshold then speaks for a mixture of two worlds. :func:`change_in_logs` tests the episodes'
statistics, in the order they ended, for a lasting change (Pettitt's test, :func:`pettitt`) and for a
burst of high ones (:func:`burst`), and :func:`calibrate_from_logs` warns of either
(:class:`ChangeInLogsWarning`) with where it is.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.hashing import other_weights
from oodmon.monitor.alarms import default_consecutive, default_window, episode_statistic
from oodmon.monitor.threshold import (DEFAULT_CONFIDENCE, DETECTOR_NAMES, Threshold, calibrate, conformal_rank,
                                      model_files, sb3_loading)
from oodmon.names import BEST_DETECTOR
from oodmon.replay.check import mid_ranks
from oodmon.replay.metrics import is_id_episode
from oodmon.replay.reader import EpisodeLog, RunLog, read_logs, read_steps
from oodmon.seeds import check_seed
from oodmon.validation import is_finite_real, is_whole

if TYPE_CHECKING:  # (the detectors load torch: replay reads logs without it)
    from oodmon.monitor.detectors.store import DetectorSet
    from oodmon.progress import Progress

__all__ = ["Burst", "Change", "ChangeInLogsWarning", "LogEpisodes", "LogStatistics", "burst", "calibrate_from_logs",
           "change_in_logs", "fit_detectors_from_logs", "log_episodes", "pettitt"]

#: :func:`calibrate_from_logs` warns of a change in the logs (:class:`ChangeInLogsWarning`) where
#: either of its two tests (Pettitt's, :func:`pettitt`, and the burst scan, :func:`burst`) gives a
#: p-value below half of this: one calibration in a hundred or fewer warns of logs of an unchanging
#: world (seeded draws of exchangeable statistics, ``tests/replay/test_recalibrate.py``).
CHANGE_LEVEL = 0.01
#: The largest share of the episodes, the highest, whose crowding in time :func:`burst` tests (it
#: scans the highest 5, 10, 20, ... up to this share).
BURST_SHARE = 0.1
#: The fewest episodes the test is made on (a calibration needs 22 at far 0.1, 45 at 0.05).
CHANGE_EPISODES = 20

#: What every log a threshold is calibrated on must share, with the words that name it: the scores
#: of two policies, score functions, sample counts or mask kinds are on two scales.
_SHARED = (("policy_hash", "policies (their weights' hashes)"), ("task", "tasks"), ("method", "methods"),
           ("score", "spread scores"), ("about.samples", "counts of samples per decision"),
           ("about.masks", "kinds of MC masks"))


@dataclass(frozen=True)
class LogEpisodes:
    """The episodes of some logs that a threshold can be calibrated on.

    Attributes:
        logs: the logs read.
        episodes: each whole ID episode, with its log.
        shifted: episodes left out as shifted (a variant, another env, or a step logged shifted).
        interrupted: episodes left out because the run was stopped inside them.
        cut: of ``episodes``, those that ended at the step an alarm began, without their env ending
            them: an alarm's callback may have stopped them (:func:`calibrate_from_logs` counts them
            as above any threshold).
        earlier: whole ID episodes left out as older than the latest ``last`` (:func:`log_episodes`).
    """

    logs: list[RunLog]
    episodes: list[tuple[RunLog, EpisodeLog]]
    shifted: int
    interrupted: int
    cut: int
    earlier: int = 0
    # change_in_logs' answers by rule: recalibrate asks again for its plot (the burst scan of
    # 10,000 episodes: 0.67 s)
    _statistics: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def noise(self, what: str) -> float:
        """The sensor noise the episodes were played with (0: none, or none recorded).

        Raises:
            ConfigError: episodes of two noises, where ``what`` (``"a threshold is calibrated"``)
                is done in one world.
        """
        noise = {float(episode.obs_noise or 0.0) for _, episode in self.episodes}
        if len(noise) > 1:
            worlds = " and ".join(f"{n:g}" for n in sorted(noise))
            raise ConfigError(f"the logs' ID episodes were played with sensor noise {worlds}: {what} in one world; "
                              "give the logs of one")
        return noise.pop() if noise else 0.0

    def left_out(self) -> dict[str, int]:
        """How many episodes were left out, and why: ``earlier`` (older than the latest ``last``),
        ``shifted`` and ``interrupted`` (see the attributes)."""
        return {"earlier": self.earlier, "shifted": self.shifted, "interrupted": self.interrupted}

    def check_some(self) -> None:
        """Raise :class:`ConfigError` where the logs hold no whole ID episode, saying what they hold."""
        if not self.episodes:
            raise ConfigError(f"the logs hold no whole ID episode ({self.shifted} shifted, {self.interrupted} "
                              "interrupted): give logs of runs of the deployed policy in its own world")


def log_episodes(logs: Sequence[str | Path | RunLog], *, last: int | None = None) -> LogEpisodes:
    """The whole ID episodes of ``logs`` (paths of MCAP files or folders, as ``oodmon replay``
    reads them, or logs read already), checked to be of one policy.

    The episodes are in the order they ended (each record's log time, the writing machine's clock),
    whatever order the logs are given in: a deployment's logs need not be named by their start, and
    several machines' logs interleave. Logs read already that hold no times (built in memory) keep
    the order given, each log's episodes in theirs.

    ``last``: the latest ``last`` of them only (all where there are fewer): a deployment that logs
    on, recalibrated on its
    latest runs (after a change in its world, those since; ``oodmon recalibrate --last N``). Only
    the logs holding them are kept and checked: older logs of a policy since retrained are left
    out with their episodes.

    Raises:
        ConfigError: no logs, or logs of two policies (or spread scores, samples, masks).
        InvalidParameterError: ``last`` is not a whole number >= 1.
        LogFormatError: a file that is not an oodmon log (see :func:`~oodmon.replay.read_logs`).
    """
    if last is not None and not is_whole(last):
        raise InvalidParameterError(f"last={last!r} is not allowed; give a whole number >= 1 of episodes, the latest "
                                    "to calibrate on (None: all)")
    if isinstance(logs, (str, Path, RunLog)):
        logs = [logs]
    if not logs:
        raise ConfigError("no logs given: name the MCAP files (or folders) of ID runs of the deployed policy")
    paths = [log for log in logs if not isinstance(log, RunLog)]
    read = [log for log in logs if isinstance(log, RunLog)] + (read_logs(paths) if paths else [])
    episodes, shifted = [], 0
    for log in read:
        for episode in log.episodes:
            if not is_id_episode(episode, log.task) or episode.shifted.any():
                shifted += 1
                continue
            episodes.append((log, episode))
    if all(episode.ended_ns is not None for _, episode in episodes):
        episodes.sort(key=lambda owned: owned[1].ended_ns)  # (stable: ties keep the order given)
        read.sort(key=lambda log: min((e.ended_ns for e in log.episodes if e.ended_ns is not None), default=0))
    earlier, interrupted = 0, sum(len(log.interrupted) for log in read)
    if last is not None and len(episodes) > last:
        earlier, episodes = len(episodes) - last, episodes[-last:]
        kept = {id(log) for log, _ in episodes}
        read = [log for log in read if id(log) in kept]
    first = read[0]
    for key, words in _SHARED:
        values = {_field(log, key) for log in read}
        if len(values) > 1:
            other = next(log for log in read if _field(log, key) != _field(first, key))
            raise ConfigError(f"the logs are of two {words}: {first.path} has {_field(first, key)!r}, "
                              f"{other.path} {_field(other, key)!r}; their scores are on two scales, read here as one "
                              "policy's: give the logs of one")
    return LogEpisodes(read, episodes, shifted, interrupted, sum(_cut(episode) for _, episode in episodes), earlier)


def fit_detectors_from_logs(agent: Any, logs: Sequence[str | Path | RunLog], *, detectors: Sequence[str] | None = None,
                            seed: int = 0, dynamics_updates: int | None = None,
                            on_progress: Progress | None = None, last: int | None = None) -> DetectorSet:
    """``agent``'s learned detectors fitted on the whole ID episodes of ``logs``, its deployment's
    own (:func:`~oodmon.monitor.detectors.fitting.fit_recorded_detectors`; the observations and
    actions of each step, :func:`~oodmon.replay.reader.read_steps`): where the deployment's world
    is not the simulator's, the detectors learn its own. The logs must be of ``agent`` (its
    weights' hash) and of one sensor noise, which the set records; ``detectors`` and
    ``dynamics_updates`` as :func:`~oodmon.monitor.detectors.fit_detectors` takes them (default:
    the agent's set, every epoch); the spread score the logs' runs read; ``last``: the latest
    episodes only (:func:`log_episodes`). Calibrate the alarm on
    other ID logs, scored by these detectors (:func:`calibrate_from_logs`): the episodes a
    detector learned read low. A policy acting on pictures (Pong) is fitted on the frames its logs
    hold: the camera's detectors and their combined, and ``features`` where the observations it
    acted on are rebuilt from them (Pong's stacks, a VecFrameStack's; see
    ``fit_recorded_detectors``); a dict's picture beside its vectors is read from the frames too.

    Raises:
        ConfigError: logs of another policy or of two sensor noises, steps with neither readings
            nor frames, too few usable episodes, a detector the logs cannot fit (see
            ``fit_recorded_detectors``).
    """
    from oodmon.monitor.detectors.fitting import fit_recorded_detectors
    from oodmon.monitor.monitor import policy_hash, policy_hash_aliases

    found = log_episodes(logs, last=last)
    first = found.logs[0]
    recorded, mine = first.metadata.get("policy_hash"), policy_hash(agent)
    if other_weights(recorded, mine, policy_hash_aliases(agent)):
        raise ConfigError(f"the logs are of another policy ({recorded[:19]}..., this one is {mine[:19]}...): fit on "
                          "logs of the policy the detectors will watch")
    found.check_some()
    noise = found.noise("detectors are fitted")
    _warn_if_changed(change_in_logs(found))
    camera = getattr(agent, "pictures", None) is not None  # a dict's picture beside its vectors: its frames too
    episodes = _steps_of(found, pictures=camera)
    return fit_recorded_detectors(agent, episodes, detectors=detectors, score=first.metadata.get("score", "chosen_std"),
                                  obs_noise=noise, seed=seed, dynamics_updates=dynamics_updates,
                                  on_progress=on_progress, recorded={"episodes": len(episodes), "logs": [
                                      str(log.path) for log in found.logs], "left_out": found.left_out()})


def _steps_of(found: LogEpisodes, *, pictures: bool = False) -> list[tuple]:
    """The observations and actions of each of ``found``'s episodes, in their order
    (:func:`~oodmon.replay.reader.read_steps`; with ``pictures``, each episode's frames third)."""
    episodes = []
    for log in found.logs:
        mine_here = [episode.episode for owner, episode in found.episodes if owner is log]
        steps = read_steps(log.path, mine_here, pictures=pictures) if mine_here else {}
        episodes += [steps[k] for k in mine_here]
    return episodes


def episodes_from_logs(logs: Sequence[str | Path | RunLog], *, last: int | None = None
                       ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every whole ID episode of ``logs`` (:func:`log_episodes`: the order they ended, ``last``
    the latest only) as ``(observations, actions)``, ``(T, ...)`` each, the records
    :func:`oodmon.monitor.fit_on_episodes`, :func:`~oodmon.monitor.calibrate_on_episodes` and
    :func:`~oodmon.monitor.validate_on_episodes` take: a deployment no env plays, watched by
    ``oodmon.watch_recorded`` with an :class:`~oodmon.monitor.McapSink`, fitted and calibrated again
    on its own logs (its hashes are those of the arrays it was given: a logged episode the
    detectors were fitted on is refused for calibration as the array was). A reading that was not
    finite reads NaN (fitting leaves such an episode out).

    Raises:
        ConfigError: no logs, or logs of two policies (:func:`log_episodes`); logs whose steps hold
            pictures, not readings (a step's newest frame, where the policy may have observed a
            stack of them).
        LogFormatError: a file that is not an oodmon log.
    """
    found = log_episodes(logs, last=last)
    found.check_some()
    episodes = [(np.asarray(steps[0]), np.asarray(steps[1])) for steps in _steps_of(found)]
    if any(observations.dtype == np.uint8 for observations, _ in episodes):
        raise ConfigError("these logs' steps hold pictures: a log keeps each step's newest frame, not always what "
                          "the policy observed (a stack of frames); fit on the pictures you recorded "
                          "(oodmon.monitor.fit_on_episodes), or, for a policy oodmon runs, `oodmon fit-detectors "
                          "--from-logs` (oodmon.replay.fit_detectors_from_logs)")
    return episodes


def _cut(episode: EpisodeLog) -> bool:
    """Whether ``episode`` ended at the step an alarm began (the monitor's alarm event, which a
    callback that stops the episode hears), its env not ending it: it may have been cut short."""
    alarm = episode.alarm
    return bool(len(alarm) and alarm[-1] and (len(alarm) == 1 or not alarm[-2]) and not episode.terminated)


def _time_limit(episodes: Sequence[tuple[RunLog, EpisodeLog]]) -> int | None:
    """The logged runs' time limit (``oodmon run --max-steps``, the env's own): the one length at
    which each episode ended that its env did not end (``terminated`` false) and no alarm may have
    cut, none of the episodes longer. ``None`` where none ran into it, where a log does not say how
    its episodes ended (before format 4) or where they ended at several lengths (runs of two
    limits, or a loop of the user's own that ended them).

    A threshold calibrated on them records it as its ``max_steps``: ``oodmon validate`` then plays
    episodes as long as those, and ``oodmon run`` runs them, as with ``calibrate --max-steps``
    (before 2026-12-06 validate played CartPole's own 500 steps against a bound for logged runs of
    200)."""
    if any(episode.terminated is None for _, episode in episodes):
        return None
    limits = {len(episode.scores) for _, episode in episodes if not episode.terminated and not _cut(episode)}
    if len(limits) != 1 or max(len(episode.scores) for _, episode in episodes) > min(limits):
        return None
    return limits.pop()


def _field(log: RunLog, key: str) -> str | None:
    """A log's ``task``, ``method`` or metadata ``key`` (``None``: not recorded)."""
    return getattr(log, key) if key in ("task", "method") else log.metadata.get(key)


def calibrate_from_logs(logs: Sequence[str | Path | RunLog] | LogEpisodes, far: float = 0.05, *,
                        confidence: float | None = DEFAULT_CONFIDENCE, detector: str | None = None,
                        consecutive: int | None = None, window: int | None = None, warmup: int = 0,
                        mode: str = "episode", last: int | None = None) -> Threshold:
    """A threshold calibrated on the whole ID episodes of ``logs`` (see the module's words; or
    their episodes read already, :func:`log_episodes`); ``last``: the latest episodes only
    (:func:`log_episodes`).

    ``detector``: the detector whose logged scores the alarm reads (default: the one the logs' runs
    alarmed on; of runs without a threshold, the task's best they scored, as ``oodmon calibrate``
    chooses); the other arguments as :func:`~oodmon.monitor.calibrate_agent`'s, whose defaults
    they share. The threshold records the policy, the fitted detector (its fingerprint: the monitor
    refuses others), the samples and masks, and the sensor noise of the logged world, as one
    calibrated by playing; ``logs`` names the logs and ``episode_seeds`` their episodes' reset seeds
    where they had any, which ``oodmon validate`` then refuses to count again; ``max_steps`` the
    runs' time limit where the logs show one (:func:`_time_limit`), which validate and run then keep;
    ``reading_names`` the names the runs gave their readings, where every log holds the same.

    Raises:
        ConfigError: logs of two policies, fitted detectors or worlds; a detector the logs have no
            scores of; too few ID episodes for ``far`` at ``confidence``.
        InvalidParameterError: a bad argument (as :func:`~oodmon.monitor.threshold.calibrate`'s).

    Example::

        threshold = calibrate_from_logs(["runs/real/"], far=0.05)  # every log below runs/real
        threshold.save("runs/real.json")
    """
    if isinstance(logs, LogEpisodes) and last is not None:
        raise InvalidParameterError("last= is for logs to read; episodes read already were chosen: give "
                                    "log_episodes(logs, last=...) instead")
    found = logs if isinstance(logs, LogEpisodes) else log_episodes(logs, last=last)
    first = found.logs[0]
    if detector is None:
        detector = _default_detector(found.logs)
    if detector not in DETECTOR_NAMES:
        raise InvalidParameterError(f"detector={detector!r} is not allowed; choose one of {', '.join(DETECTOR_NAMES)}")
    for log in found.logs:
        logged = log.metadata.get("detectors", "spread").split(",")
        if detector not in logged:
            raise ConfigError(f"{log.path} holds no {detector} scores (its run scored {', '.join(logged)}): calibrate "
                              f"on one of those, or log runs whose monitor reads fitted {detector} detectors")
    fitted = {log.metadata.get(f"fitted.{detector}") for log in found.logs}
    if len(fitted) > 1:
        raise ConfigError(f"the logs' {detector} scores come from two fits of the detectors "
                          f"({', '.join(map(str, fitted))}): each fit scores on a scale of its own; give the logs of "
                          "runs of one")
    detectors_hash = fitted.pop()
    if detector != "spread" and detectors_hash is None:
        raise ConfigError(f"{first.path} does not record which fit of the {detector} detector scored it (a log written "
                          "before 2026-11-29): the monitor could not check it reads the same; log new runs")
    noise = found.noise("a threshold is calibrated")
    found.check_some()
    if mode == "episode":
        try:
            conformal_rank(len(found.episodes), far, confidence)
        except ConfigError as error:  # (which says how many it needs)
            raise ConfigError(f"the logs hold {len(found.episodes)} whole ID episodes ({found.shifted} shifted and "
                              f"{found.interrupted} interrupted left out): {error}; log more ID runs") from None
    if mode != "episode" and found.cut:
        raise ConfigError(f"{found.cut} of the logs' ID episodes ended at the step an alarm began, their env not "
                          "ending them: an alarm may have cut them short, and their steps after it are unknown; "
                          "calibrate per episode (mode='episode', --mode episode), which counts them above any "
                          "threshold")
    whole = [(log, episode) for log, episode in found.episodes if not _cut(episode)]
    scores = [episode.scores_of(detector) for _, episode in whole]
    threshold = calibrate(
        scores, far, consecutive=default_consecutive(detector) if consecutive is None else consecutive, mode=mode,
        score=first.metadata.get("score", "chosen_std"), task=first.task, method=first.method,
        window=default_window(first.task, detector) if window is None else window, policy_hash=first.metadata.get(
            "policy_hash"), detector=detector, confidence=confidence, masks=first.metadata.get("about.masks"),
        warmup=warmup, detectors_hash=detectors_hash, samples=_samples(first), above=len(found.episodes) - len(whole))
    threshold = replace(threshold, obs_noise=noise, max_steps=_time_limit(found.episodes),
                        episode_seeds=_seed_runs(found.episodes),
                        logs=[{"path": str(log.path), "run_id": log.metadata.get("run_id"),
                               "episodes": sum(1 for owner, _ in found.episodes if owner is log)}
                              for log in found.logs], models=_logged_models(first),
                        sb3=sb3_loading({key.removeprefix("about."): value for key, value in first.metadata.items()
                                         if key.startswith("about.")}), reading_names=_logged_names(found.logs))
    _warn_if_changed(change_in_logs(found, threshold), threshold)
    return threshold


class ChangeInLogsWarning(UserWarning):
    """:func:`calibrate_from_logs`, :func:`fit_detectors_from_logs`: the logged episodes'
    statistics change over the logs (:func:`change_in_logs`), so that they may not be one world's."""


@dataclass(frozen=True)
class Change:
    """Pettitt's most likely change in a sequence of values: ``at``, the first value after it
    (counted from 0), the two parts' medians, and the test's approximate p-value under no change
    (the values exchangeable)."""

    at: int
    p_value: float
    before: float
    after: float


def pettitt(values: Sequence[float]) -> Change:
    """Pettitt's (1979) test for one change in the level of ``values`` in their order: the split
    whose values before and after differ most by the Mann-Whitney statistic (``U_t = 2 R_t - t (n
    + 1)``, ``R_t`` the sum of the first ``t`` mid-ranks), and ``p ~ 2 exp(-6 K^2 / (n^3 + n^2))``
    for ``K = max |U_t|`` (capped at 1; it errs high, as the test needs). A rise or fall that
    lasts, a drift as well as a step, moves ``K``; NaN counts as the highest value.

    Raises:
        InvalidParameterError: ``values`` that are not a one-dimensional sequence of numbers.

    Example:
        >>> change = pettitt([1, 2, 1, 3, 2, 1, 2, 9, 8, 9, 7, 8, 9, 8])
        >>> change.at, round(change.p_value, 4), change.before, change.after
        (7, 0.0149, 2.0, 8.0)
    """
    x = _ordered_values(values)
    n = len(x)
    if n < 2:
        return Change(0, 1.0, math.nan, math.nan)
    ranks, _ = mid_ranks(x.tolist())
    t = np.arange(1, n)
    u = 2 * np.cumsum(ranks)[:-1] - t * (n + 1)
    split = int(np.argmax(np.abs(u)))
    k = float(abs(u[split]))
    p_value = min(1.0, 2.0 * math.exp(-6.0 * k * k / (float(n) ** 3 + float(n) ** 2)))
    return Change(split + 1, p_value, float(np.median(x[:split + 1])), float(np.median(x[split + 1:])))


def _ordered_values(values: Sequence[float]) -> np.ndarray:
    """``values`` as the tests of :func:`pettitt` and :func:`burst` read them: floats in their
    order, NaN as +inf (the highest).

    Raises:
        InvalidParameterError: ``values`` that are not a one-dimensional sequence of numbers.
    """
    if isinstance(values, (str, bytes)):
        raise InvalidParameterError("values is text; give a sequence of numbers, in their order")
    try:
        x = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"values={values!r:.40} is not a sequence of numbers; give one, in their order") \
            from None
    if x.ndim != 1:
        raise InvalidParameterError(f"values has shape {x.shape}; give a sequence of numbers (one dimension)")
    return np.where(np.isnan(x), math.inf, x)


@dataclass(frozen=True)
class Burst:
    """The most crowded stretch of the highest values in their order (:func:`burst`): ``first``
    and ``last`` (counted from 0) bound the window of ``size`` consecutive values holding ``count``
    of the ``size`` highest; ``p_value``, the share of random orders as crowded at some size
    (permutations, over every size scanned: ``sizes``)."""

    first: int
    last: int
    count: int
    size: int
    p_value: float
    sizes: tuple[int, ...] = ()


def burst(values: Sequence[float], *, share: float = BURST_SHARE, permutations: int = 1000, seed: int = 0
          ) -> Burst | None:
    """Whether some of the highest values of ``values`` crowd into a stretch of their order: a
    burst of runs unlike the others, such as a fault or a shift nobody flagged for a while, which a
    test of one lasting change (:func:`pettitt`) hardly sees. Scanned at several sizes (ties broken
    at random): the highest 5, 10, 20, ... up to the ``share`` highest (5 at least); at each, the
    most of them in any window as long as their number. Each size's crowding is ranked among
    ``permutations`` random orders (seeded by ``seed``) and the order itself; the p-value is the
    share of those orders whose most crowded size ranks as high (the least of the sizes' shares,
    compared alike: the scan over sizes is paid for). A few runs set a threshold: of far 0.05 on
    200 episodes it is their sixth highest statistic. Five runs among 200 raised by four standard
    deviations, scanned at the highest tenth alone, were found in 5 of 100 seeded draws; at every
    size, in 100 (``tests/replay/test_recalibrate.py``). The stretch reported is that of the size
    ranking highest (of sizes ranking alike, that whose crowd is the least likely by chance in one
    window of a random order, a hypergeometric tail: eight runs among 200 are said as 8 of the 10
    highest, not 10 of the 20). ``None`` where the highest would be half the values or more (too
    few to tell a crowd). NaN counts as the highest value.

    Raises:
        InvalidParameterError: ``values`` that are not a one-dimensional sequence of numbers, a
            ``share`` outside (0, 0.5), a count of ``permutations`` or a ``seed`` that is not one.

    Example:
        >>> values = [0.1 * (k % 7) for k in range(60)]
        >>> values[30:36] = [9.0] * 6  # six runs of another world among sixty
        >>> found = burst(values)
        >>> found.first, found.last, found.count, found.size, found.sizes, found.p_value < 0.005
        (30, 35, 6, 6, (5, 6), True)
    """
    if not (is_finite_real(share) and 0 < share < 0.5):
        raise InvalidParameterError(f"share={share!r} is not allowed; give the share of the highest values, "
                                    "0 < share < 0.5")
    if not is_whole(permutations) or permutations > 10**6:
        raise InvalidParameterError(f"permutations={permutations!r} is not allowed; give a whole number 1-1,000,000")
    seed = check_seed(seed)
    x = _ordered_values(values)
    n, top = len(x), max(5, math.ceil(share * len(x)))
    if 2 * top > n:
        return None
    sizes = tuple(sorted({min(5 * 2**k, top) for k in range(top.bit_length()) if 5 * 2**k < 2 * top}))
    rng = np.random.default_rng(seed)
    rank = np.empty(n, np.int64)
    rank[np.lexsort((rng.random(n), -x))] = np.arange(n)  # 0: the highest (ties in a random order)

    def crowds(ranks: np.ndarray) -> list[np.ndarray]:
        """For each size, each row's count of its highest in each window of that size."""
        found = []
        for size in sizes:
            sums = np.cumsum(ranks < size, axis=1, dtype=np.int32)
            found.append(np.concatenate([sums[:, size - 1:size], sums[:, size:] - sums[:, :-size]], axis=1))
        return found

    windows = [w[0] for w in crowds(rank[None])]
    most = [np.array([int(w.max()) for w in windows])]  # the order itself first, then the random ones
    for done in range(0, permutations, 100):  # (a hundred orders at a time: bounded memory)
        orders = rng.permuted(np.tile(rank, (min(100, permutations - done), 1)), axis=1)
        most.append(np.stack([w.max(axis=1) for w in crowds(orders)], axis=1))
    counts = np.vstack(most)  # (1 + permutations, sizes)
    # each order's rank at each size: the share of the orders as crowded or more; its best size
    shares = np.stack([(len(c) - np.searchsorted(np.sort(c), c, side="left")) / len(c) for c in counts.T], axis=1)
    best = shares.min(axis=1)
    # the stretch said: of the sizes ranking alike (a thousand orders cannot rank the most crowded
    # apart), that whose crowd is the least likely in a window of random order
    tied = [j for j in range(len(sizes)) if shares[0, j] == best[0]]
    at = min(tied, key=lambda j: (_log_crowd_chance(n, sizes[j], int(windows[j].max())), -j))
    size, window = sizes[at], windows[at]
    start = int(np.argmax(window))
    inside = np.flatnonzero(rank[start:start + size] < size) + start
    return Burst(int(inside[0]), int(inside[-1]), int(window[start]), size, float(np.mean(best <= best[0])), sizes)


def _log_crowd_chance(n: int, size: int, count: int) -> float:
    """The log of the chance that a window of ``size`` of ``n`` values in random order holds
    ``count`` or more of their ``size`` highest (hypergeometric), times the windows: how unlikely a
    crowd is, to tell sizes apart where the permutations rank them alike."""
    def log_comb(a: int, b: int) -> float:
        return math.lgamma(a + 1) - math.lgamma(b + 1) - math.lgamma(a - b + 1)

    terms = [log_comb(size, k) + log_comb(n - size, size - k) for k in range(count, size + 1) if size - k <= n - size]
    most = max(terms)
    return most + math.log(sum(math.exp(t - most) for t in terms)) - log_comb(n, size) + math.log(n - size + 1)


@dataclass(frozen=True)
class LogStatistics:
    """Each calibration episode of some logs with its statistic under a threshold's rule, in the
    order they ended (:func:`log_episodes`), Pettitt's most likely change in them (:func:`pettitt`)
    and the most crowded stretch of the highest (:func:`burst`; each ``None`` for fewer than
    :data:`CHANGE_EPISODES` episodes), of the scores of ``detector``. An episode an alarm may have
    cut short reads +inf."""

    episodes: list[tuple[RunLog, EpisodeLog]]
    values: np.ndarray
    change: Change | None
    detector: str = "spread"
    burst: Burst | None = None

    def where(self, index: int) -> str:
        """The ``index``-th episode in words: its log and its number there."""
        log, episode = self.episodes[index]
        return f"{log.path} episode {episode.episode}"


def change_in_logs(found: LogEpisodes, threshold: Threshold | None = None) -> LogStatistics:
    """The statistics of the whole ID episodes ``found`` (:func:`log_episodes`) under
    ``threshold``'s rule (its detector's logged scores; an episode an alarm may have cut short:
    +inf, as calibration counts it), in the order they ended, tested for a change (:func:`pettitt`).
    ``None``: the rule calibration would choose by default (the detector the logs' runs alarmed on,
    else the task's best they scored; its default ``consecutive`` and ``window``).

    The threshold's promise speaks for episodes like its calibration episodes taken together: a
    change among them (a world drifting while it was logged, a shift nobody flagged among runs
    taken for ID) means they may not be one world, and the promise not the one for the world to
    come. Detectors fitted on them learn both worlds."""
    if threshold is None:
        try:
            detector = _default_detector(found.logs)
        except ConfigError:  # runs that alarmed on two detectors: the spread, which every log holds
            detector = "spread"
        consecutive, window, warmup = default_consecutive(detector), default_window(found.logs[0].task, detector), 0
    else:
        detector, consecutive, window, warmup = (threshold.detector, threshold.consecutive, threshold.window,
                                                 threshold.warmup)
    rule = (detector, consecutive, window, warmup)
    if rule not in found._statistics:
        values = np.array([math.inf if _cut(episode) else episode_statistic(
            episode.scores_of(detector), consecutive, window, warmup=warmup) for _, episode in found.episodes],
            dtype=np.float64)
        enough = len(values) >= CHANGE_EPISODES
        found._statistics[rule] = LogStatistics(list(found.episodes), values, pettitt(values) if enough else None,
                                                detector, burst(values) if enough else None)
    return found._statistics[rule]


def _warn_if_changed(statistics: LogStatistics, threshold: Threshold | None = None) -> None:
    """Warn (:class:`ChangeInLogsWarning`) where the statistics change, or where their highest
    crowd into a stretch (each test at half :data:`CHANGE_LEVEL`), of episodes ``threshold`` is
    calibrated on (``None``: detectors are fitted on them). A calibration's warning says how often
    the threshold alarms on each side of the change (or in the stretch and elsewhere) beside its
    target: a change that matters leaves one side far from it, one too small to matter neither."""
    n, level = len(statistics.values), CHANGE_LEVEL / 2
    change, crowd = statistics.change, statistics.burst
    use = "fitting" if threshold is None else "calibration"
    what = ("Detectors fitted on both worlds take both for ID: a change from one to the other goes unseen"
            if threshold is None else f"The promise holds for episodes like the {n} taken together, not for either "
                                      "world alone")
    again = "fit the detectors" if threshold is None else "calibrate"
    plot = "(`oodmon recalibrate --plot FILE` draws each episode's statistic in order)"
    harm = "teach detectors to read them as ID" if threshold is None else "raise a threshold to their level"
    if change is not None and change.p_value < level:
        later = "higher" if change.after > change.before else "lower"
        sides = _alarmed_on_sides(statistics.values, threshold, range(change.at), "before",
                                  range(change.at, n), "since")
        warnings.warn(ChangeInLogsWarning(
            f"the {use} episodes' {statistics.detector} statistics change over the logs (Pettitt's test, p = "
            f"{change.p_value:.2g}): from {statistics.where(change.at)} on ({change.at + 1} of {n} in the order they "
            f"ended) they read {later}, median {change.after:.4g} against {change.before:.4g} before{sides}. {what}: "
            f"if the later runs were not in distribution, leave their logs out; if the world has moved on, {again} "
            f"on its latest episodes (`--last {n - change.at}`: those since) {plot}"), stacklevel=3)
    elif crowd is not None and crowd.p_value < level:
        inside = range(crowd.first, crowd.last + 1)
        sides = _alarmed_on_sides(statistics.values, threshold, inside, "in the stretch",
                                  [i for i in range(n) if i not in inside], "elsewhere")
        warnings.warn(ChangeInLogsWarning(
            f"the {crowd.size} highest {statistics.detector} statistics of the {n} {use} episodes crowd into a stretch "
            f"of the logs: {crowd.count} of them from {statistics.where(crowd.first)} to "
            f"{statistics.where(crowd.last)} ({crowd.first + 1}-{crowd.last + 1} in the order they ended; p = "
            f"{crowd.p_value:.2g} over random orders){sides}. Runs unlike the others for a while (a fault, a shift "
            f"nobody flagged) {harm}: if they were not in distribution, leave them out (their logs, or the runs of "
            f"that time) {plot}"), stacklevel=3)


def _alarmed_on_sides(values: np.ndarray, threshold: Threshold | None, one: Sequence[int], one_said: str,
                      other: Sequence[int], other_said: str) -> str:
    """``; this threshold alarms in a of the N before and b of the M since (target far)``: how
    often ``threshold``'s rule alarms among the calibration episodes of two parts (their
    statistics above its value); ``""`` without a threshold (a fit)."""
    if threshold is None:
        return ""
    counts = [(int(np.sum(values[list(part)] > threshold.value)), len(part)) for part in (one, other)]
    (a, n_a), (b, n_b) = counts
    return (f"; this threshold alarms in {a} of the {n_a} {one_said} and {b} of the {n_b} {other_said} (its target: "
            f"{threshold.far:g} of the episodes)")


def _default_detector(logs: Sequence[RunLog]) -> str:
    """The detector the logs' runs alarmed on; of runs without a threshold (which raised no alarm),
    the one ``oodmon calibrate`` would choose among those they scored: the task's best
    (:data:`~oodmon.names.BEST_DETECTOR`), else ``spread``, else (a plain policy's) the last."""
    alarmed_on = {log.metadata.get("detector", "spread") for log in logs if math.isfinite(log.threshold)}
    if len(alarmed_on) > 1:
        raise ConfigError(f"the logs' runs alarmed on {' and '.join(sorted(alarmed_on))}: name the detector whose "
                          "scores the threshold is for (detector=, --detector)")
    if alarmed_on:
        return alarmed_on.pop()
    scored = [log.metadata.get("detectors", "spread").split(",") for log in logs]
    best = BEST_DETECTOR.get(logs[0].task, "combined")
    if all(best in names for names in scored):
        return best
    return "spread" if all("spread" in names for names in scored) else scored[0][-1]


def _logged_models(log: RunLog) -> list[dict[str, str]] | None:
    """The SB3 model files a log's policy was loaded from (``about.models``), as
    :attr:`Threshold.models` holds them (:func:`~oodmon.monitor.threshold.model_files`).

    Example:
        >>> from types import SimpleNamespace as Log
        >>> _logged_models(Log(metadata={"about.models": '[{"path": "a.zip", "sha256": "ab", "algorithm": "DQN"}]'}))
        [{'path': 'a.zip', 'sha256': 'ab'}]
        >>> _logged_models(Log(metadata={"about.models": "not JSON"})) is None
        True
    """
    try:
        return model_files(json.loads(log.metadata.get("about.models") or "null"))
    except ValueError:
        return None


def _logged_names(logs: Sequence[RunLog]) -> list[str] | None:
    """The reading names the logs' runs were given, or read from a dict observation's keys
    (``about.reading_names``), where every log holds the same (``None``: none, or logs that differ).

    Example:
        >>> from types import SimpleNamespace as Log
        >>> _logged_names([Log(reading_names=("x", "v")), Log(reading_names=("x", "v"))])
        ['x', 'v']
        >>> _logged_names([Log(reading_names=("x", "v")), Log(reading_names=())]) is None
        True
    """
    names = {log.reading_names for log in logs}
    return list(names.pop()) if len(names) == 1 and () not in names else None


def _samples(log: RunLog) -> int | None:
    """The samples per decision a log's policy drew (``None``: not recorded)."""
    samples = log.metadata.get("about.samples")
    return int(samples) if samples is not None and samples.isdigit() else None


def _seed_runs(episodes: Sequence[tuple[RunLog, EpisodeLog]]) -> dict[str, list[int]] | None:
    """The episodes' reset seeds as ``[first, end)`` runs of consecutive seeds, by use
    (``calibration``, then ``calibration 2``, ...), as :attr:`Threshold.episode_seeds` holds them;
    ``None`` where no episode had a seed (a deployment that does not seed its resets).

    Example:
        >>> from types import SimpleNamespace as E
        >>> _seed_runs([(None, E(seed=s)) for s in (5, 6, 7, 20, None)])
        {'calibration': [5, 8], 'calibration 2': [20, 21]}
    """
    seeds = sorted({episode.seed for _, episode in episodes if episode.seed is not None})
    runs: list[list[int]] = []
    for seed in seeds:
        if runs and runs[-1][1] == seed:
            runs[-1][1] = seed + 1
        else:
            runs.append([seed, seed + 1])
    return {("calibration" if i == 0 else f"calibration {i + 1}"): run for i, run in enumerate(runs)} or None
