"""What watches: per-step uncertainty scores, calibrated thresholds, alarms, MCAP and Rerun sinks.

- :class:`Monitor` wraps a deployed policy (a loaded agent or an estimator) and scores each step;
  :class:`MonitoredEnv` does it as a gymnasium wrapper.
- :func:`calibrate` turns held-out ID episodes into a :class:`Threshold` with a per-episode
  false-alarm guarantee; :func:`calibrate_agent` runs those episodes.
- Sinks: :class:`MemorySink`, :class:`McapSink`; a failing sink warns and the loop goes on.
"""

from __future__ import annotations

from oodmon.monitor.alarms import DEFAULT_CONSECUTIVE, AlarmEvent, AlarmTracker, episode_statistic
from oodmon.monitor.calibration import CALIBRATION_SEED, calibrate_agent, id_episode_scores
from oodmon.monitor.monitor import AlarmCallback, Monitor, MonitoredEnv
from oodmon.monitor.records import EpisodeRecord, RunInfo, StepRecord
from oodmon.monitor.scores import DEFAULT_SCORE, SCORES, score_function
from oodmon.monitor.sinks import McapSink, MemorySink, RerunSink, Sink, SinkGroup, SinkWarning
from oodmon.monitor.threshold import Threshold, calibrate

__all__ = [
    "CALIBRATION_SEED",
    "DEFAULT_CONSECUTIVE",
    "DEFAULT_SCORE",
    "SCORES",
    "AlarmCallback",
    "AlarmEvent",
    "AlarmTracker",
    "EpisodeRecord",
    "McapSink",
    "MemorySink",
    "Monitor",
    "RerunSink",
    "MonitoredEnv",
    "RunInfo",
    "Sink",
    "SinkGroup",
    "SinkWarning",
    "StepRecord",
    "Threshold",
    "calibrate",
    "calibrate_agent",
    "episode_statistic",
    "id_episode_scores",
    "score_function",
]
