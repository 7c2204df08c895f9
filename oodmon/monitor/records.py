"""What the monitor records: one :class:`StepRecord` per step, one :class:`EpisodeStart` and one
:class:`EpisodeRecord` per episode, one :class:`RunInfo` per run. Sinks write them; replay reads
them back from the logs."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from oodmon.monitor.alarms import AlarmEvent, Region

__all__ = ["EpisodeRecord", "EpisodeSegment", "EpisodeStart", "RunInfo", "StepRecord"]


@dataclass(frozen=True)
class StepRecord:
    """One monitored step.

    Attributes:
        episode: the episode's index in the run (0, 1, ...).
        step: the step's index in the episode; the observation is the one the policy acted on.
        action: the deployed action (an int for DQN, a list of floats for DDPG).
        mean: per action (DQN: Q-values) or action dimension (DDPG: actions), the mean of the samples.
        std: the same, the standard deviation of the samples.
        score: the score the alarm rule reads (the alarm detector's).
        threshold: the threshold in force (``nan`` without one).
        alarm: whether the alarm rule holds at this step.
        shifted: whether the observation came from the shifted world (the env's ``info``).
        observation: the observation (vector tasks; stacked vectors flattened), or ``None``.
        frame: the observed image (Pong: the newest 84x84 frame the agent saw), or ``None``.
        scores: every detector's score at this step, by detector name (``spread``, ``dynamics``, ...).
        compared: what the alarm rule compared with the threshold where that is not the score
            (:attr:`~oodmon.monitor.alarms.AlarmTracker.compared`): a window's mean (NaN until
            the window fills), a CUSUM or martingale statistic; NaN under a rule that compares
            each score. The MCAP sink logs it as ``compared`` (format 9), the Rerun sink draws it
            as ``/compared``.
        raised: the alarm raised at this step (:class:`~oodmon.monitor.alarms.AlarmEvent`), or
            ``None``: the MCAP sink logs its cause and readings with the step (``raised``, format
            11), so that a killed run's running episode replays them too.
    """

    episode: int
    step: int
    action: int | list[float]
    mean: list[float]
    std: list[float]
    score: float
    threshold: float
    alarm: bool
    shifted: bool
    observation: list[float] | None = None
    frame: np.ndarray | None = field(default=None, repr=False, compare=False)
    scores: dict[str, float] = field(default_factory=dict)
    compared: float = field(default=math.nan, repr=False, compare=False)
    raised: AlarmEvent | None = field(default=None, repr=False, compare=False)

    def to_json(self) -> dict[str, Any]:
        """The fields logged as JSON (the frame goes to an image channel instead)."""
        data = {name: getattr(self, name) for name in
                ("episode", "step", "action", "mean", "std", "score", "threshold", "alarm", "shifted")}
        if self.observation is not None:
            data["observation"] = self.observation
        if self.scores:
            data["scores"] = self.scores
        if self.raised is not None:
            data["raised"] = {"cause": self.raised.cause or None,
                              "readings": [[index, residual] for index, residual in self.raised.readings],
                              "readings_steps": self.raised.readings_steps}
            if self.raised.region is not None:  # (format 12)
                data["raised"]["region"] = self.raised.region._asdict()
        return data


@dataclass(frozen=True)
class EpisodeStart:
    """What is known of an episode at its first step: where it runs (written with that step, so a
    log torn inside a long episode still says what its steps were)."""

    episode: int
    env_id: str = ""
    variant: str = ""
    onset: int = 0
    seed: int | None = None
    obs_noise: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {"episode": self.episode, "env_id": self.env_id, "variant": self.variant, "onset": self.onset,
                "seed": self.seed, "obs_noise": self.obs_noise}


@dataclass(frozen=True)
class EpisodeSegment:
    """A long episode's steps from ``start`` up to the step about to be written (or the episode's
    end), handed on so that sinks drop what they keep of them (``Monitor(segment_steps=)``).

    Attributes:
        episode: the episode's index in the run.
        start: the segment's first step.
        rewards: the reward of each of its steps; ``None`` where they were not all given.
    """

    episode: int
    start: int
    rewards: tuple[float, ...] | None = field(default=None, repr=False)


@dataclass(frozen=True)
class EpisodeRecord:
    """One finished episode.

    Attributes:
        episode: the episode's index in the run.
        env_id: the gymnasium id, e.g. ``oodmon/CartPole-v1``.
        variant: the variant's spec, e.g. ``cartpole:length=2.0``.
        onset: the step from which the shift is active (0 for the whole episode).
        seed: the seed of ``reset``.
        total_return: the sum of the rewards.
        length: the number of steps.
        alarms: the number of alarms raised.
        first_alarm_step: the step of the first alarm, or ``None``.
        interrupted: the run was stopped inside this episode (Ctrl-C, an exception): it did not
            end by itself, so replay leaves it out of the metrics.
        terminated: the env ended the episode itself (``terminated``: the pole fell, the game was
            lost or won), not a time limit or an alarm; ``None`` where the loop did not say
            (logs older than format 4, a loop of your own).
        first_alarm_cause: what raised the first alarm's score (:attr:`AlarmEvent.cause
            <oodmon.monitor.alarms.AlarmEvent.cause>`), or ``None`` (no alarm; logs older than
            format 7; an episode cut at a tear).
        obs_noise: the env's sensor noise (``obs_noise`` of oodmon's CartPole and Pendulum: its std
            as a fraction of each observation dimension's ID spread); 0 for any other env, and in
            logs older than format 8.
        first_alarm_readings: the readings the first alarm named (:attr:`AlarmEvent.readings
            <oodmon.monitor.alarms.AlarmEvent.readings>`), and ``first_alarm_readings_steps`` the
            steps their residuals cover; empty (and 1) without an alarm, where it named none, and in
            logs older than format 10.
        first_alarm_region: where in the picture the first alarm's events fell
            (:attr:`AlarmEvent.region <oodmon.monitor.alarms.AlarmEvent.region>`); ``None`` without
            one, and in logs older than format 12.
        rewards: the reward of each step (what ``add_reward`` received), logged in the episode's
            score arrays; ``None`` where they were not given step by step, or the episode was
            longer than a segment (``Monitor(segment_steps=)``: the log holds them by segment).
    """

    episode: int
    env_id: str
    variant: str
    onset: int
    seed: int | None
    total_return: float
    length: int
    alarms: int
    first_alarm_step: int | None
    interrupted: bool = False
    terminated: bool | None = None
    first_alarm_cause: str | None = None
    obs_noise: float = 0.0
    first_alarm_readings: tuple[tuple[int, float], ...] = ()
    first_alarm_readings_steps: int = 1
    first_alarm_region: Region | None = None
    rewards: tuple[float, ...] | None = field(default=None, repr=False, compare=False)

    @property
    def alarmed_early(self) -> bool:
        """The first alarm came before the onset (in a shifted episode: a false alarm)."""
        return self.first_alarm_step is not None and self.first_alarm_step < self.onset

    @property
    def delay(self) -> int | None:
        """Steps from the onset to the first alarm; ``None`` without an alarm or when the first one
        came before the onset. (Replay, which has every step's alarm, also times an alarm after an
        early one: ``oodmon.replay.compute_metrics``.)

        Example:
            >>> record = EpisodeRecord(0, "oodmon/CartPole-v1", "cartpole:length=2.0", onset=100, seed=0,
            ...                        total_return=104.0, length=104, alarms=1, first_alarm_step=101)
            >>> record.delay, record.alarmed_early
            (1, False)
        """
        if self.first_alarm_step is None or self.alarmed_early:
            return None
        return self.first_alarm_step - self.onset

    def to_json(self) -> dict[str, Any]:
        """The episode message (the rewards go to the episode's score arrays instead)."""
        return {"episode": self.episode, "env_id": self.env_id, "variant": self.variant, "onset": self.onset,
                "seed": self.seed, "return": self.total_return, "length": self.length, "alarms": self.alarms,
                "first_alarm_step": self.first_alarm_step, "interrupted": self.interrupted,
                "terminated": self.terminated, "first_alarm_cause": self.first_alarm_cause, "obs_noise": self.obs_noise,
                "first_alarm_readings": [[index, residual] for index, residual in self.first_alarm_readings],
                "first_alarm_readings_steps": self.first_alarm_readings_steps,
                "first_alarm_region": None if self.first_alarm_region is None else self.first_alarm_region._asdict()}


@dataclass(frozen=True)
class RunInfo:
    """What a run's log says about the run as a whole (written as MCAP metadata)."""

    task: str
    method: str
    score: str
    threshold: float
    rule: str
    policy_hash: str
    versions: dict[str, str]
    detector: str = "spread"
    detectors: tuple[str, ...] = ("spread",)
    #: Where the policy came from and how the run was started: ``command`` (the process's command
    #: line), ``machine`` (its CPU kind, since 2026-11-29), and for models from elsewhere ``env_id``
    #: and ``models`` (JSON: each file's path, sha256 and algorithm).
    about: dict[str, str] = field(default_factory=dict)
    #: The fingerprint of each learned detector's fit (and of those it combines), by name
    #: (:meth:`~oodmon.monitor.detectors.DetectorSet.fingerprint`): scores of two fits are on two
    #: scales, and replay says when it pools them. Logs written before 2026-11-29 have none.
    fitted: dict[str, str] = field(default_factory=dict)

    def to_strings(self) -> dict[str, str]:
        """MCAP metadata holds strings only."""
        return {"task": self.task, "method": self.method, "score": self.score, "threshold": repr(self.threshold),
                "rule": self.rule, "policy_hash": self.policy_hash, "detector": self.detector,
                "detectors": ",".join(self.detectors), **{f"version.{k}": v for k, v in self.versions.items()},
                **{f"about.{k}": v for k, v in self.about.items()}, **{f"fitted.{k}": v for k, v in self.fitted.items()}}
