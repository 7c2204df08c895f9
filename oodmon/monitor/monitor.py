"""The runtime monitor: the policy's action, its uncertainty score, the alarm rule, the logs.

Three ways to use it:

- a loop of your own: ``monitor.begin_episode(...)``, then ``action = monitor.step(obs,
  shifted=...)`` and ``monitor.add_reward(r)`` per step, then ``monitor.end_episode()``;
- ``monitor.run_episode(env, seed=...)`` runs the whole loop in an env;
- :class:`MonitoredEnv` wraps an env: ``env.step()`` without an action lets the monitored policy
  act; with an action (yours, say a safe fallback after an alarm) the monitor still scores and
  logs the policy's view of the step.

A :class:`Monitor` is a context manager over a run: it opens its sinks on entry and closes them
(finishing the files) on exit, also after an exception.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium
import numpy as np

from oodmon.agents.agent import Agent
from oodmon.agents.estimators import UncertaintyEstimator
from oodmon.errors import ConfigError
from oodmon.monitor.alarms import DEFAULT_CONSECUTIVE, AlarmEvent, AlarmTracker
from oodmon.monitor.records import EpisodeRecord, RunInfo, StepRecord
from oodmon.monitor.scores import DEFAULT_SCORE, score_function
from oodmon.monitor.sinks.base import Sink, SinkGroup
from oodmon.monitor.threshold import Threshold
from oodmon.versions import library_versions

__all__ = ["AlarmCallback", "Monitor", "MonitoredEnv"]

#: Called with each alarm; returning True asks ``run_episode`` / ``MonitoredEnv`` to end the
#: episode (the default is to let the policy go on).
AlarmCallback = Callable[[AlarmEvent], "bool | None"]


def _policy_hash(agent: Agent | None) -> str:
    if agent is None or agent.path is None:
        return "unknown"
    path = agent.path / "model.safetensors"
    return "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else "unknown"


class Monitor:
    """Wraps a deployed policy; scores every step against a calibrated threshold.

    Args:
        policy: a loaded :class:`~oodmon.agents.Agent` or any uncertainty estimator.
        threshold: a :class:`Threshold` (its score and rule are used), a number, or ``None``
            (scores are logged, no alarms).
        score: the score's name when ``threshold`` is not a :class:`Threshold`.
        consecutive: m of the alarm rule when ``threshold`` is not a :class:`Threshold`.
        window: the alarm rule's averaging window when ``threshold`` is not a :class:`Threshold`.
        sinks: where records go (:class:`MemorySink`, :class:`McapSink`, :class:`RerunSink`).
        callbacks: called with every :class:`AlarmEvent`.
        strict: a failing sink raises instead of warning.
        log_observations: put what the agent observed into the step records: vector observations
            as numbers, image observations (Pong) as the ``frame`` given to :meth:`step`. Off, the
            records carry scores only (calibration keeps no frames in memory).

    Example:
        >>> from oodmon.agents import load
        >>> from oodmon.monitor import MemorySink
        >>> sink = MemorySink()
        >>> with Monitor(load("cartpole", "ensemble"), threshold=4.6, sinks=[sink]) as monitor:
        ...     record = monitor.run_episode(gymnasium.make("oodmon/CartPole-v1", length=2.0), seed=0)
        >>> len(sink.steps) == record.length, record.first_alarm_step is not None
        (True, True)
    """

    def __init__(
        self,
        policy: Agent | UncertaintyEstimator,
        threshold: Threshold | float | None = None,
        *,
        score: str | None = None,
        consecutive: int | None = None,
        window: int | None = None,
        sinks: Sequence[Sink] = (),
        callbacks: Sequence[AlarmCallback] = (),
        strict: bool = False,
        log_observations: bool = True,
    ) -> None:
        self.agent = policy if isinstance(policy, Agent) else None
        self.estimator = policy.estimator if isinstance(policy, Agent) else policy
        if isinstance(threshold, Threshold):
            if score is not None and score != threshold.score:
                raise ConfigError(f"score={score!r} contradicts the threshold file's score {threshold.score!r}")
            score, consecutive, value = threshold.score, threshold.consecutive, threshold.value
            window = threshold.window
        else:
            value = math.nan if threshold is None else float(threshold)
        self.threshold = value
        self.score_name = score or DEFAULT_SCORE
        self._score = score_function(self.score_name)
        self.tracker = AlarmTracker(value, consecutive or DEFAULT_CONSECUTIVE, window or 1)
        self.sinks = SinkGroup(list(sinks), strict=strict)
        self.callbacks = list(callbacks)
        self.log_observations = log_observations
        self.episode = -1
        self._opened = False
        self._in_episode = False
        self.stop_requested = False

    # -- the run -----------------------------------------------------------------------------
    def open(self) -> Monitor:
        if not self._opened:
            meta = self.agent.metadata if self.agent is not None else {}
            self.sinks.open(RunInfo(
                task=meta.get("task", "unknown"), method=meta.get("method", "unknown"), score=self.score_name,
                threshold=self.threshold, rule=self.tracker.rule, policy_hash=_policy_hash(self.agent),
                versions=library_versions(),
            ))
            self._opened = True
        return self

    def close(self) -> None:
        if self._opened:
            self.sinks.close()
            self._opened = False

    def __enter__(self) -> Monitor:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- an episode ----------------------------------------------------------------------------
    def begin_episode(self, *, env_id: str = "", variant: str = "", onset: int = 0, seed: int | None = None) -> None:
        self.open()
        self.episode += 1
        self.tracker.reset()
        self._episode_info = dict(env_id=env_id, variant=variant, onset=onset, seed=seed)
        self._return, self._length, self._alarms, self._first_alarm = 0.0, 0, 0, None
        self._in_episode = True
        self.stop_requested = False

    def step(self, obs: np.ndarray, *, shifted: bool = False, frame: np.ndarray | None = None) -> int | np.ndarray:
        """Score the observation the policy acts on; log it; return the deployed action."""
        if not self._in_episode:
            raise ConfigError("Monitor.step before begin_episode: start an episode first (or use run_episode)")
        estimate = self.estimator.estimate(obs)
        score = float(self._score(estimate)[0])
        step = self._length
        alarm, event = self.tracker.update(self.episode, step, score)
        raw = estimate.action[0]
        action: int | np.ndarray = int(raw) if self.estimator.kind == "q_values" else np.asarray(raw)
        observation = None
        if self.log_observations and np.ndim(obs) == 1:
            observation = [float(x) for x in obs]
        if not self.log_observations:
            frame = None
        self.sinks.write_step(StepRecord(
            episode=self.episode, step=step, action=action if isinstance(action, int) else action.tolist(),
            mean=estimate.mean[0].tolist(), std=estimate.std[0].tolist(), score=score, threshold=self.threshold,
            alarm=alarm, shifted=bool(shifted), observation=observation, frame=frame,
        ))
        if event is not None:
            self._alarms += 1
            if self._first_alarm is None:
                self._first_alarm = step
            self.sinks.write_alarm(event)
            for callback in self.callbacks:
                if callback(event):
                    self.stop_requested = True
        self._length += 1
        return action

    def add_reward(self, reward: float) -> None:
        self._return += float(reward)

    def end_episode(self) -> EpisodeRecord:
        record = EpisodeRecord(self.episode, total_return=self._return, length=self._length, alarms=self._alarms,
                               first_alarm_step=self._first_alarm, **self._episode_info)
        self.sinks.end_episode(record)
        self._in_episode = False
        return record

    def run_episode(self, env: gymnasium.Env, *, seed: int | None = None, variant: str | None = None,
                    max_steps: int | None = None) -> EpisodeRecord:
        """Run the monitored policy for one episode of ``env``; return the episode's record."""
        base = env.unwrapped
        onset = int(getattr(base, "onset_step", 0))
        spec_id = env.spec.id if env.spec is not None else type(base).__name__
        self.begin_episode(env_id=spec_id, variant=variant or spec_id, onset=onset, seed=seed)
        obs, info = env.reset(seed=seed)
        try:
            while True:
                action = self.step(obs, shifted=bool(info.get("shifted", False)), frame=_frame(obs))
                obs, reward, terminated, truncated, info = env.step(action)
                self.add_reward(reward)
                if terminated or truncated or self.stop_requested or (max_steps and self._length >= max_steps):
                    break
        finally:
            record = self.end_episode()
        return record


def _frame(obs: np.ndarray) -> np.ndarray | None:
    """The newest frame of a stacked image observation (Pong), else None."""
    return obs[-1] if np.ndim(obs) == 3 and obs.dtype == np.uint8 else None


class MonitoredEnv(gymnasium.Wrapper):
    """An env whose steps are scored and logged by a :class:`Monitor`.

    ``step()`` with no action lets the monitored policy act; ``step(action)`` takes your action
    (the monitor still scores and logs the policy's estimate at that observation).

    Example:
        >>> from oodmon.agents import load
        >>> env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"), Monitor(load("cartpole", "dropout")))
        >>> obs, info = env.reset(seed=0)
        >>> obs, reward, terminated, truncated, info = env.step()
        >>> env.monitor.episode, reward
        (0, 1.0)
    """

    def __init__(self, env: gymnasium.Env, monitor: Monitor, *, variant: str | None = None) -> None:
        super().__init__(env)
        self.monitor = monitor
        self.variant = variant
        self._obs: Any = None
        self._info: dict = {}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if self.monitor._in_episode:
            self.monitor.end_episode()
        obs, info = self.env.reset(seed=seed, options=options)
        spec_id = self.env.spec.id if self.env.spec is not None else type(self.env.unwrapped).__name__
        self.monitor.begin_episode(env_id=spec_id, variant=self.variant or spec_id,
                                   onset=int(getattr(self.env.unwrapped, "onset_step", 0)), seed=seed)
        self._obs, self._info = obs, info
        return obs, info

    def step(self, action: Any = None):
        chosen = self.monitor.step(self._obs, shifted=bool(self._info.get("shifted", False)), frame=_frame(self._obs))
        obs, reward, terminated, truncated, info = self.env.step(chosen if action is None else action)
        self.monitor.add_reward(reward)
        truncated = truncated or self.monitor.stop_requested
        if terminated or truncated:
            self.monitor.end_episode()
        self._obs, self._info = obs, info
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        if self.monitor._in_episode:
            self.monitor.end_episode()
        self.monitor.close()
        super().close()
