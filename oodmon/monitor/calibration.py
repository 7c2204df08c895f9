"""Run held-out in-distribution episodes of an agent and calibrate its threshold on them.

The calibration episodes use seeds from :data:`CALIBRATION_SEED` on, apart from the seeds of
training's evaluations (10,000 + steps) and of the ID return (100,000 + i), so they are held out.
"""

from __future__ import annotations

import os
import shutil
import warnings
from collections.abc import Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from oodmon import seeds
from oodmon.agents.agent import Agent
from oodmon.envs.checks import warn_if_endless
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.jsonfile import check_replaceable
from oodmon.kept import KeptEpisodesWarning, SamplingTrail, read_kept, state_array, state_of, unreadable, write_kept
from oodmon.monitor.alarms import default_consecutive, default_window
from oodmon.monitor.detectors import DetectorSet, best_detector
from oodmon.monitor.monitor import Monitor, OffCalibrationWarning, check_reading_names, policy_hash
from oodmon.monitor.scores import DEFAULT_SCORE, score_function
from oodmon.monitor.sequential import SEQUENTIAL_RULES, Reference
from oodmon.monitor.threshold import (DEFAULT_CONFIDENCE, DETECTOR_NAMES, Stretches, Threshold, calibrate,
                                     check_step_episodes, clopper_pearson, clustered_interval, conformal_rank,
                                     episodes_needed, model_files, sb3_loading, verdict_of)
from oodmon.progress import Progress
from oodmon.seeds import EPISODE_USES, use_words
from oodmon.side_by_side import finished_before, play_side_by_side, resolve_workers, stream_per_episode
from oodmon.validation import check_max_steps, is_step_count, is_whole

__all__ = ["CALIBRATION_SEED", "EPISODE_USES", "KeptEpisodesWarning", "Stretches", "Validation", "calibrate_agent",
           "check_fresh", "check_max_steps", "clopper_pearson", "detectors_read", "id_episode_scores",
           "read_kept_episodes", "reused_episodes", "save_calibration", "seeds_used", "validate_threshold"]

CALIBRATION_SEED = seeds.CALIBRATION
#: ID episodes a sequential rule's p-values are taken against.
DEFAULT_REFERENCE_EPISODES = 20


class _ScoresAndAlarms:
    """A sink keeping what calibration and validation read of each episode: the alarm detector's
    per-step scores and the steps at which alarms were raised, not whole step records (validation's
    episodes may be long: ``--max-steps``)."""

    def __init__(self) -> None:
        self.episodes: list[tuple[np.ndarray, list[int]]] = []
        self._scores: list[float] = []
        self._alarms: list[int] = []

    def open(self, run: Any) -> None:
        pass

    def write_step(self, record: Any) -> None:
        self._scores.append(record.score)

    def write_alarm(self, event: Any) -> None:
        self._alarms.append(event.step)

    def end_episode(self, record: Any) -> None:
        if not record.interrupted:  # an episode cut by Ctrl-C is not one of those asked for
            self.episodes.append((np.asarray(self._scores), self._alarms))
        self._scores, self._alarms = [], []

    def close(self) -> None:
        pass


def _play_id_episodes(agent: Agent, episodes: int, seed: int, obs_noise: float,
                      on_progress: Progress | None, stage: str = "ID episodes", workers: int = 1,
                      max_steps: int | None = None, **settings: Any) -> list[tuple[np.ndarray, list[int]]]:
    """Run ``episodes`` ID episodes of ``agent`` under a :class:`Monitor` made with ``settings``
    (seeds ``seed`` on, sensor noise ``obs_noise``); of each, the alarm detector's per-step scores
    and the steps at which an alarm was raised. ``on_progress(stage, done, episodes)`` after each.
    ``max_steps``: each episode's time limit (the env's own lifted or set: ``max_episode_steps``).

    ``workers``: processes that play them side by side (0: one per core; see
    :mod:`oodmon.side_by_side` for what an MC agent draws there).

    Interrupted (Ctrl-C, SIGTERM), the ``KeyboardInterrupt`` carries the results of the first
    episodes played whole (:func:`~oodmon.side_by_side.finished_before`): side by side, each worker
    plays runs of about a tenth of its share, so that one interrupted loses little."""
    seed = seeds.check_seed(seed)
    workers = resolve_workers(workers, episodes)
    start = stream_per_episode(agent.estimator, workers)

    def play(first: int, count: int, done) -> list[tuple[np.ndarray, list[int]]]:
        sink = _ScoresAndAlarms()
        env = agent.make_env(obs_noise, max_steps=max_steps)
        endless = None if max_steps is not None else (lambda _, steps, __: warn_if_endless(env, steps))
        try:
            with warnings.catch_warnings(), Monitor(agent, sinks=[sink], log_observations=False, **settings) as monitor:
                # validate counts false alarms at another noise, or in longer episodes, on purpose, and says so
                warnings.simplefilter("ignore", OffCalibrationWarning)
                for episode in range(first, first + count):
                    start(seed + episode)
                    monitor.run_episode(env, seed=seed + episode, variant=agent.task, on_progress=endless)
                    done()
        except KeyboardInterrupt as interrupt:  # (one process: those played whole, from ``first``)
            interrupt.finished = list(sink.episodes)
            raise
        env.close()
        return sink.episodes

    return play_side_by_side(play, episodes, workers, stage, on_progress, run_size=-(-episodes // (10 * workers)))


def id_episode_scores(agent: Agent, episodes: int, *, seed: int = CALIBRATION_SEED, score: str = DEFAULT_SCORE,
                      on_progress: Progress | None = None, detectors: DetectorSet | None = None,
                      detector: str = "spread", obs_noise: float = 0.0, stage: str = "ID episodes",
                      workers: int = 1, max_steps: int | None = None,
                      reading_names: Sequence[str] | None = None) -> list[np.ndarray]:
    """Per-step scores of ``detector`` in ``episodes`` ID episodes of ``agent``, seeded ``seed``,
    ``seed + 1``, ... (with sensor noise ``obs_noise``, see the envs, and time limit ``max_steps``,
    ``None``: the env's own), played in ``workers`` processes (see :mod:`oodmon.side_by_side`).
    ``reading_names``: as the :class:`Monitor`'s (their count checked at the first step)."""
    check_max_steps(max_steps)
    played = _play_id_episodes(agent, episodes, seed, obs_noise, on_progress, score=score, detectors=detectors,
                               detector=detector, stage=stage, workers=workers, max_steps=max_steps,
                               reading_names=reading_names)
    return [scores for scores, _ in played]


def calibrate_agent(agent: Agent, episodes: int = 50, far: float = 0.05, *, consecutive: int | None = None,
                    mode: str = "episode", score: str = DEFAULT_SCORE, seed: int = CALIBRATION_SEED,
                    on_progress: Progress | None = None, window: int | None = None,
                    detectors: DetectorSet | None = None, detector: str | None = None,
                    obs_noise: float = 0.0, confidence: float | None = DEFAULT_CONFIDENCE, rule: str = "consecutive",
                    reference_episodes: int = DEFAULT_REFERENCE_EPISODES, reference_by_age: bool = False,
                    warmup: int = 0, workers: int = 1, max_steps: int | None = None,
                    kept: str | Path | None = None, reading_names: Sequence[str] | None = None) -> Threshold:
    """Calibrate ``agent``'s threshold on ``episodes`` held-out ID episodes (see ``threshold``).

    ``detector`` names the detector whose score the alarm will read; a learned one comes from
    ``detectors`` (fitted on other episodes, :func:`~oodmon.monitor.detectors.fit_detectors`).
    By default it is the task's best measured detector when ``detectors`` has it, else ``spread``
    (:func:`~oodmon.monitor.detectors.best_detector`).

    ``confidence`` (1 - d): with this probability over the calibration episodes, the threshold's
    false-alarm rate is at most ``far`` (``None``: on average over calibrations; see ``threshold``).

    ``consecutive``: m of the rule (default: 3 for ``spread``, 1 for a learned detector,
    :func:`~oodmon.monitor.alarms.default_consecutive`). ``window``: the rule compares the mean
    score of the last ``window`` steps (default: :func:`~oodmon.monitor.alarms.default_window`).

    ``rule``: ``consecutive`` (m steps in a row), or a sequential rule, ``cusum`` or
    ``martingale``, whose p-values are taken against ``reference_episodes`` further ID episodes
    (seeds :data:`oodmon.seeds.REFERENCE` on, apart from the calibration ones; see ``sequential``),
    pooled or, with ``reference_by_age``, by time since reset.

    ``warmup``: the rule looks at no finite score of an episode's first ``warmup`` steps (see
    ``alarms``); the threshold is calibrated for that rule.

    ``max_steps``: the episodes' time limit instead of the env's own, for a deployment whose runs are
    longer (the bound is for episodes like the calibration's); recorded in the threshold, whose
    validation plays episodes that long.

    ``workers``: processes that play the episodes side by side (0: one per core). An agent that
    draws nothing when it decides gets the same threshold from any number; an MC agent's episodes
    draw from streams of their own there, the same for any ``workers`` >= 2 and not those of one
    process (:mod:`oodmon.side_by_side`).

    ``kept``: a file (``.npz``) where an interrupted calibration (Ctrl-C, SIGTERM, or a worker's
    death: killed when memory ran out) keeps the scores of its first calibration episodes played
    whole, and from which a calibration of the same policy, detector, seed and world goes on: it
    plays only the episodes after them. The ``KeyboardInterrupt`` (``BrokenProcessPool``) then
    carries their number in ``.kept_episodes``. A file made otherwise is
    not read (:class:`KeptEpisodesWarning`). The caller removes it once the threshold is saved.
    The threshold is the uninterrupted calibration's: side by side each episode draws from a
    stream of its own, and in one process the file keeps where an MC agent's draws stood after the
    episodes kept (:class:`~oodmon.kept.SamplingTrail`), which the calibration that goes on draws
    on from.

    ``reading_names``: the name of each number of the observations the detectors read, by index
    (as the :class:`Monitor`'s): the threshold records them, and a monitor with it names its
    alarms' readings by them (``oodmon run`` without ``--reading-names``).

    Raises:
        InvalidParameterError, ConfigError: a bad argument, too few episodes for ``far``, or
            calibration episodes that are not held out: ``detectors``' fitting episodes (the
            detectors learned them) or the sequential rule's reference episodes; all checked before
            the first episode runs, but ``reading_names``' count (at its first step).
    """
    # Every argument is checked before minutes of episodes: a dry run of the calibration on
    # placeholder scores raises what the real one would.
    if not is_whole(episodes):
        raise InvalidParameterError(f"episodes={episodes!r} is not allowed; give a whole number >= 1 of ID episodes")
    check_max_steps(max_steps)
    seed = seeds.check_seed(seed)
    resolve_workers(workers, episodes)
    score_function(score)
    names = check_reading_names(reading_names)
    if detector is None:
        detector = best_detector(agent.task, detectors, score)
    if detector not in DETECTOR_NAMES:
        raise InvalidParameterError(f"detector={detector!r} is not allowed; choose one of {', '.join(DETECTOR_NAMES)}")
    if (detector == "spread" and agent.estimator is None) or (detectors is not None and detector not in detectors):
        from oodmon.monitor.detectors.fitting import check_can_have

        check_can_have(detector, agent, detectors)
    if detector != "spread" and (detectors is None or detector not in detectors):
        raise ConfigError(f"calibrating the {detector} detector needs it fitted: pass detectors=fit_detectors(...) "
                          "(`oodmon fit-detectors`)")
    if consecutive is None:
        consecutive = default_consecutive(detector)
    if window is None:
        window = default_window(agent.task, detector)
    # The steps the rule reads of an episode (a count it refuses is refused by the dry run below;
    # until then it counts as the least allowed)
    steps = sum(n if is_step_count(n, least) else least for n, least in ((consecutive, 1), (window, 1), (warmup, 0))) - 1
    if rule != "consecutive" and not is_whole(reference_episodes):
        raise InvalidParameterError(f"reference_episodes={reference_episodes!r} is not allowed; the {rule} rule needs a "
                                    "whole number >= 1 of ID reference episodes")
    placeholder = Reference.from_episodes([np.zeros(1)]) if rule in SEQUENTIAL_RULES else None
    if mode == "episode":
        conformal_rank(episodes, far, confidence)  # too few episodes for far: said before the first is played
    elif confidence is not None:
        check_step_episodes(episodes, far, confidence)
    # As many placeholder episodes as the promise needs at the least, not ``episodes`` of them: 10**30
    # asked numpy for too much, and in step mode their few steps stood for the real episodes' many
    # (10 CartPole episodes, 5,000 steps, were refused as "30 steps", 2026-12-05). The steps are
    # counted when the real calibration has them.
    calibrate([np.zeros(max(steps, 1))] * episodes_needed(far, confidence), far, consecutive=consecutive, mode=mode,
              score=score, window=window, confidence=confidence, rule=rule, reference=placeholder, warmup=warmup)
    agent.check_noise(obs_noise)  # a noise the env refuses, or an env without it: said before the first episode
    needed = detectors.subset([detector]) if detectors is not None and detector != "spread" else None
    _warn_of_other_noise(needed, obs_noise)
    held = _fitted_on(needed) | ({"reference": [seeds.REFERENCE, seeds.REFERENCE + reference_episodes]}
                                 if rule != "consecutive" else {})
    clashes, free = _overlaps(held, seed, episodes, seeds.CALIBRATION)
    if clashes:  # (2026-12-05: calibrated on its detectors' 90 fitting episodes, the CartPole ensemble's
        # threshold was 4.18 against 5.93, and alarmed 7 of 300 fresh ID episodes against 2)
        raise ConfigError(f"the calibration episodes (seeds {seed:,}-{seed + episodes - 1:,}) are not held out: they "
                          f"include {clashes}, whose scores are not those of a fresh episode, so the threshold's "
                          f"promise would not hold; give a first seed (--seed) apart from them, e.g. {free}")
    reference = None
    if rule != "consecutive":
        reference = Reference.from_episodes(id_episode_scores(
            agent, reference_episodes, seed=seeds.REFERENCE, score=score, detectors=needed, detector=detector,
            obs_noise=obs_noise, workers=workers, max_steps=max_steps, reading_names=names), by_age=reference_by_age)
    # what the threshold records of the policy and the detector, and what a kept file must have been made by
    policy, fitted = policy_hash(agent), None if needed is None else needed.fingerprint(detector)
    masks = getattr(agent.estimator, "masks", None)
    samples = None if agent.estimator is None else agent.estimator.n_samples
    made_by = None if kept is None else {
        "policy": policy, "task": agent.task, "detector": detector, "score": score, "detectors": fitted, "seed": seed,
        "obs_noise": float(obs_noise), "max_steps": max_steps, "masks": masks, "samples": samples}
    scores, state = ([], None) if kept is None else _read_kept(kept, made_by)
    scores = scores[:episodes]
    if scores and on_progress is not None:
        on_progress("kept calibration episodes", len(scores), episodes)  # (an interrupted calibration's)
    # an MC agent in one process draws on from where the kept episodes left it
    trail = SamplingTrail(agent.estimator, resolve_workers(workers, max(1, episodes - len(scores))))
    trail.resume(state)
    try:
        if len(scores) < episodes:
            scores += id_episode_scores(agent, episodes - len(scores), seed=seed + len(scores), score=score,
                                        on_progress=trail.progress(on_progress), detectors=needed, detector=detector,
                                        obs_noise=obs_noise, stage="calibration episodes", workers=workers,
                                        max_steps=max_steps, reading_names=names)
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:  # (Ctrl-C, SIGTERM, a worker's death)
        if kept is not None:
            played = [episode for episode, _ in finished_before(interrupt)]  # (each: its scores, its alarms)
            scores += played
            interrupt.kept_episodes = _keep_episodes(kept, made_by, scores, trail.state_after(len(played), state)
                                                     ) if scores else 0
        raise
    _check_steps_to_score(scores, detector, needed)
    threshold = calibrate(scores, far, consecutive=consecutive, mode=mode, score=score, task=agent.task,
                          method=agent.method, window=window, policy_hash=policy, detector=detector,
                          confidence=confidence, rule=rule, reference=reference, masks=masks, warmup=warmup,
                          detectors_hash=fitted, samples=samples)
    used = {"calibration": [seed, seed + episodes]}
    if reference is not None:
        used["reference"] = [seeds.REFERENCE, seeds.REFERENCE + reference_episodes]
    return replace(threshold, episode_seeds=used, workers=resolve_workers(workers, episodes),
                   obs_noise=float(obs_noise), max_steps=max_steps, models=model_files(agent.metadata.get("models")),
                   sb3=sb3_loading(agent.metadata), reading_names=None if names is None else list(names))


def read_kept_episodes(path: str | Path, made_by: dict[str, Any]) -> list[np.ndarray]:
    """The per-step scores of the calibration episodes an interrupted :func:`calibrate_agent` kept
    in ``path`` (see its ``kept``), where a calibration ``made_by`` the same settings kept them;
    ``[]`` where there is no such file, and with a :class:`KeptEpisodesWarning` where it is one of
    another calibration's or unreadable (:func:`oodmon.kept.read_kept`). Nothing in it is unpickled."""
    return _read_kept(path, made_by)[0]


def _read_kept(path: str | Path, made_by: dict[str, Any]) -> tuple[list[np.ndarray], dict | None]:
    """:func:`read_kept_episodes`' scores, and where an MC agent's draws stood after them in one
    process (:class:`~oodmon.kept.SamplingTrail`), or ``None``."""
    kept = read_kept(path, made_by, "calibration", stacklevel=4)  # (the caller of calibrate_agent, or of ours)
    if not kept:
        return [], None
    try:
        scores, lengths = kept["scores"].astype(np.float64), kept["lengths"].astype(np.int64)
        state = state_of(kept)
    except (KeyError, ValueError) as error:  # (json's JSONDecodeError is a ValueError)
        unreadable(path, "calibration", f"no {error}", stacklevel=4)
        return [], None
    if lengths.ndim != 1 or scores.ndim != 1 or lengths.sum() != len(scores) or (lengths < 0).any():
        unreadable(path, "calibration", "its steps do not add up", stacklevel=4)
        return [], None
    return (np.split(scores, np.cumsum(lengths)[:-1]) if len(lengths) else []), state


def _keep_episodes(path: str | Path, made_by: dict[str, Any], scores: list[np.ndarray],
                   state: dict | None = None) -> int:
    """Write the calibration episodes' ``scores`` (and ``state``, where an MC agent's draws stood
    after them) to ``path`` whole or not at all (see ``kept``); how many were kept: 0 where the disk
    is full (said in a warning: the interrupt goes on as one)."""
    try:
        write_kept(path, made_by, {"scores": np.concatenate(scores), **state_array(state),
                                   "lengths": np.array([len(s) for s in scores], dtype=np.int64)})
    except OSError as error:
        warnings.warn(f"the {len(scores):,} calibration episodes played whole are not kept: {error}", stacklevel=4)
        return 0
    return len(scores)


def _warn_of_other_noise(detectors: DetectorSet | None, obs_noise: float) -> None:
    """Warn where the learned detectors were fitted in a world of other sensor noise than the
    calibration's: their ID scores there are not those they learned, so the threshold sits where the
    noise puts it (the dynamics model learns the noise as variance, docs/detectors.md)."""
    fitted = None if detectors is None else detectors.fitted_for.get("obs_noise")
    if fitted is not None and fitted != obs_noise:
        warnings.warn(f"the detectors were fitted with sensor noise obs_noise={fitted:g} and the calibration "
                      f"episodes have {obs_noise:g}: fit them in the world they will watch (`oodmon "
                      f"fit-detectors --obs-noise {obs_noise:g}`, or calibrate without --detectors)",
                      UserWarning, stacklevel=3)


#: Detectors that score the change into an observation from the one before it (an episode's first
#: observation gets a neutral score: there is nothing before it).
READ_CHANGES = frozenset({"dynamics", "drift", "transitions"})


def _check_steps_to_score(scores: Sequence[np.ndarray], detector: str, detectors: DetectorSet | None) -> None:
    """Refuse to calibrate an alarm that cannot fire: one that reads only changes between
    observations (:data:`READ_CHANGES`, or ``combined`` of them alone), in ID episodes that all last
    one step. The monitor scores the observations the policy acts on, and in an episode of one step
    that is its first, which no change led to: a contextual bandit (one decision an episode) got
    "alarm when score > -0" from every ID score alike and alarmed at nothing (2026-12-01)."""
    reads = set(detectors["combined"].members) if detector == "combined" and detectors is not None else {detector}
    if not scores or any(len(episode) > 1 for episode in scores) or not reads <= READ_CHANGES:
        return
    raise ConfigError(f"every ID episode lasted one step: the {detector} detector scores the change into each "
                      "observation the policy acts on from the one before it, and an episode's first has none, so its "
                      "alarm could not see a shift in episodes this short. The spread and features detectors read the "
                      "observation itself: they watch an ensemble (several SB3 models, --sb3 A.zip B.zip) or an MC agent")


def save_calibration(threshold: Threshold, path: str | Path, detectors: DetectorSet | None = None) -> None:
    """The threshold at ``path`` and, if given, the detectors it was calibrated with at
    ``<path>.detectors/`` (where ``oodmon run --threshold`` and ``watch(threshold=...)`` find them).

    The threshold is written beside its place first, then the detectors (:meth:`DetectorSet.save`
    moves its files in whole, or keeps the set that was there), and only then is the threshold
    moved in, so that a full disk or a failure while writing leaves the earlier pair whole (written
    one after the other, a failure of the second left a threshold and detectors of two calibrations,
    which ``run`` refuses). Only a kill between the moves, which need no room, can still part them.
    """
    path = Path(path)
    check_replaceable(path)  # (/dev/zero: refused before the detectors are written beside it)
    folder, threshold_part = Path(f"{path}.detectors"), path.with_name(path.name + ".part")
    made = detectors is not None and not folder.exists()
    try:
        threshold.save(threshold_part)
        if detectors is not None:  # moved in whole by DetectorSet.save, or the set that was there kept
            detectors.save(folder)
    except BaseException:
        threshold_part.unlink(missing_ok=True)
        if made:
            shutil.rmtree(folder, ignore_errors=True)
        raise
    os.replace(threshold_part, path)


@dataclass(frozen=True)
class Validation:
    """A threshold checked on fresh ID episodes.

    Attributes:
        alarmed: episodes (steps in step mode) that raised an alarm.
        total: episodes (steps) played.
        far, confidence: the threshold's target and the confidence of its bound.
        low, high: the 95% interval of the realised false-alarm rate: Clopper-Pearson's over the
            episodes; in step mode with each episode's steps counted as a cluster
            (:func:`~oodmon.monitor.threshold.clustered_interval`), as the steps of one episode
            alarm together.
        obs_noise: the sensor noise of the episodes played.
        steps, alarms: ID steps played and alarms raised over them (every excursion above the
            threshold, not only an episode's first).
        max_steps: the episodes' time limit, where validation set one (else the env's own).
        stretches: in episode mode, where ``max_steps`` is not the threshold's own (its calibration
            episodes were shorter): the episodes cut into stretches as long as the calibration's
            episodes on average (:class:`Stretches`), which the verdict then reads; else ``None``.
        design_effect: in step mode, how much the episodes' clustering widened the interval (1:
            not at all); ``None`` in episode mode.
        episodes: the episodes played (``total`` in episode mode).
    """

    alarmed: int
    total: int
    far: float
    confidence: float | None
    low: float
    high: float
    obs_noise: float = 0.0
    steps: int = 0
    alarms: int = 0
    max_steps: int | None = None
    stretches: Stretches | None = None
    design_effect: float | None = None
    episodes: int | None = None

    @property
    def rate(self) -> float:
        return self.alarmed / self.total

    @property
    def verdict(self) -> str:
        """``above`` (the whole interval exceeds the target), ``below`` (it is under), or
        ``consistent`` (the target is inside it: more episodes would tell); of the stretches where
        the episodes were longer than calibration's (:attr:`stretches`)."""
        low, high = (self.low, self.high) if self.stretches is None else (self.stretches.low, self.stretches.high)
        return verdict_of(low, high, self.far)


def detectors_read(threshold: Threshold, detectors: DetectorSet | None) -> DetectorSet | None:
    """The fitted detector ``threshold``'s alarm reads, of ``detectors``, as a set of its own
    (``None``: the spread, which is not fitted, or a detector ``detectors`` does not have)."""
    wanted = threshold.detector
    return detectors.subset([wanted]) if detectors is not None and wanted != "spread" and wanted in detectors else None


def seeds_used(threshold: Threshold, detectors: DetectorSet | None = None) -> dict[str, list[int]]:
    """The reset seeds of the ID episodes ``threshold`` was made from, by use, each ``[first, end)``:
    those it records (:attr:`Threshold.episode_seeds`) and, with ``detectors`` (those its alarm
    reads), the episodes they were fitted on (``fitted_for``: ``seed``, ``episodes``).

    Example:
        >>> found = calibrate([np.zeros(5)] * 45, 0.05, consecutive=1)
        >>> seeds_used(replace(found, episode_seeds={"calibration": [200_000, 200_045]}))
        {'calibration': [200000, 200045]}
    """
    return dict(threshold.episode_seeds or {}) | _fitted_on(detectors)


def _fitted_on(detectors: DetectorSet | None) -> dict[str, list[int]]:
    """The reset seeds of the ID episodes ``detectors`` were fitted on (``fitted_for``: ``seed``,
    ``episodes``), ``{"detector fitting": [first, end)}``, or ``{}`` where they do not say."""
    fitted = detectors.fitted_for if detectors is not None else {}
    if is_whole(fitted.get("seed"), 0) and is_whole(fitted.get("episodes"), 1):
        return {"detector fitting": [fitted["seed"], fitted["seed"] + fitted["episodes"]]}
    return {}


def reused_episodes(threshold: Threshold, detectors: DetectorSet | None, seed: int, episodes: int) -> tuple[str, int]:
    """Which of the episodes ``seed`` .. ``seed + episodes - 1`` ``threshold`` or its ``detectors``
    were made from (:func:`seeds_used`), in words (``""``: none), and a first seed whose
    ``episodes`` episodes miss every recorded range (the validation range's first where it can).

    Example:
        >>> found = calibrate([np.zeros(5)] * 45, 0.05, consecutive=1)
        >>> reused_episodes(replace(found, episode_seeds={"calibration": [0, 45]}), None, 40, 10)
        ("the threshold's calibration episodes (seeds 0-44)", 700000)
    """
    return _overlaps(seeds_used(threshold, detectors), seed, episodes, seeds.VALIDATION)


def _overlaps(used: dict[str, list[int]], seed: int, episodes: int, start: int) -> tuple[str, int]:
    """Which of the ranges ``used`` (by use, each ``[first, end)``) the episodes ``seed`` .. ``seed +
    episodes - 1`` fall in, in words (``""``: none), and a first seed from ``start`` on whose
    ``episodes`` episodes miss them all."""
    clashes = [f"{use_words(name)} episodes (seeds {first:,}-{end - 1:,})" for name, (first, end) in used.items()
               if first < seed + episodes and seed < end]
    free = start
    while any(first < free + episodes and free < end for first, end in used.values()):
        free = max(end for first, end in used.values() if first < free + episodes and free < end)
    return " and ".join(clashes), free


def check_fresh(threshold: Threshold, detectors: DetectorSet | None, seed: int, episodes: int) -> None:
    """Refuse to validate ``threshold`` on episodes ``seed`` .. ``seed + episodes - 1`` where any
    of them is one the threshold or its ``detectors`` were made from (:func:`seeds_used`): a
    threshold is the largest statistic of its calibration episodes (or near it), so they alarm
    by construction at most as often as its rank lets them, and the detectors learned their
    fitting episodes; counted as fresh, either reads as a false-alarm rate below the true one.
    Measured: the CartPole ensemble's threshold (combined > 5.74836, 50 calibration episodes from
    200,000) alarmed 0 of its own 50 and 0 of its detectors' 90 fitting episodes.

    Raises:
        ConfigError: the overlap, and a seed whose episodes miss every recorded range.
    """
    reused, free = reused_episodes(threshold, detectors, seed, episodes)
    if reused:
        raise ConfigError(f"the validation episodes (seeds {seed:,}-{seed + episodes - 1:,}) are not fresh: they "
                          f"include {reused}, which the threshold was made from and which alarm less often than "
                          f"fresh ones; give a first seed (--seed) apart from them, e.g. {free}")


def validate_threshold(agent: Agent, threshold: Threshold, episodes: int = 200, *, seed: int = seeds.VALIDATION,
                       detectors: DetectorSet | None = None, obs_noise: float | None = None, force: bool = False,
                       on_progress: Progress | None = None, workers: int = 1,
                       max_steps: int | None = None) -> Validation:
    """Play ``episodes`` fresh ID episodes (seeds ``seed`` on, apart from calibration's) under a
    :class:`Monitor` with ``threshold`` and count those that raised an alarm (in step mode: the
    steps above it): the realised false-alarm rate beside the target. ``workers``: processes that
    play them side by side (0: one per core; see :func:`calibrate_agent`). ``obs_noise``: the
    episodes' sensor noise (``None``: the threshold's, ``Threshold.obs_noise``, 0 where it records none).
    ``max_steps``: each episode's time limit instead of the env's own, to check the threshold on runs
    as long as a deployment's (``None``: the threshold's, :attr:`Threshold.max_steps`, else the
    env's own); in episode mode the episodes are then also counted by stretches as long as the
    calibration's episodes (:class:`Stretches`), which the bound speaks of.

    Interrupted (Ctrl-C, SIGTERM), the ``KeyboardInterrupt`` raised carries in ``.validation`` the
    count of the first episodes played whole (``None``: none was).

    Raises:
        InvalidParameterError: ``episodes`` is not a whole number >= 1.
        ConfigError: the threshold was made for another policy (unless ``force``) or reads a
            detector ``detectors`` does not have (the monitor's own checks); the episodes are not
            fresh: one of them is one the threshold or its detectors were made from
            (:func:`check_fresh`).
    """
    if not isinstance(threshold, Threshold):
        raise InvalidParameterError(f"threshold={threshold!r:.60} is not allowed; give a Threshold (Threshold.load(path) "
                                    "of a file `oodmon calibrate` or calibrate_agent wrote)")
    if not is_whole(episodes):
        raise InvalidParameterError(f"episodes={episodes!r} is not allowed; give a whole number >= 1 of ID episodes")
    check_max_steps(max_steps)
    seed = seeds.check_seed(seed)
    resolve_workers(workers, episodes)
    if obs_noise is None:
        obs_noise = threshold.calibration_noise
    if max_steps is None:
        max_steps = threshold.max_steps
    agent.check_noise(obs_noise)  # as calibrate_agent: said before the first episode
    needed = detectors_read(threshold, detectors)
    check_fresh(threshold, needed, seed, episodes)
    try:
        played = _play_id_episodes(agent, episodes, seed, obs_noise, on_progress, stage="validation episodes",
                                   workers=workers, threshold=threshold, detectors=needed, force=force,
                                   max_steps=max_steps)
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:  # what was played whole goes with it
        finished = finished_before(interrupt)
        interrupt.validation = _counted(finished, threshold, obs_noise, max_steps) if finished else None
        raise
    return _counted(played, threshold, obs_noise, max_steps)


def _counted(played: list[tuple[np.ndarray, list[int]]], threshold: Threshold, obs_noise: float,
             max_steps: int | None) -> Validation:
    """The :class:`Validation` of the ID episodes ``played`` (each: its scores and alarm steps)."""
    design_effect = None
    if threshold.mode == "episode":
        alarmed, total = sum(bool(alarms) for _, alarms in played), len(played)
        low, high = clopper_pearson(int(alarmed), total)
    else:  # the steps above the threshold, each episode's counted together
        interval = clustered_interval([(int(np.sum(scores > threshold.value)), len(scores)) for scores, _ in played])
        alarmed, total, low, high = interval.successes, interval.trials, interval.low, interval.high
        design_effect = interval.design_effect
    stretches = None
    if max_steps is not None and max_steps != threshold.max_steps and threshold.mode == "episode":
        stretches = Stretches.of([(len(scores), alarms) for scores, alarms in played], threshold.mean_episode)
    return Validation(int(alarmed), total, threshold.far, threshold.confidence, low, high, float(obs_noise),
                      steps=sum(len(scores) for scores, _ in played), alarms=sum(len(alarms) for _, alarms in played),
                      max_steps=max_steps, stretches=stretches, design_effect=design_effect, episodes=len(played))
