"""What watches: per-step uncertainty scores, calibrated thresholds, alarms, MCAP and Rerun sinks.

- :class:`Monitor` wraps a deployed policy (a loaded agent or an estimator) and scores each step;
  :class:`MonitoredEnv` does it as a gymnasium wrapper.
- :func:`calibrate` turns held-out ID episodes into a :class:`Threshold` with a per-episode
  false-alarm bound; :func:`calibrate_agent` runs those episodes; :func:`validate_threshold`
  checks a threshold on fresh ones.
- :func:`watch_recorded` makes the monitor of a deployment oodmon cannot play from its recorded ID
  episodes (:func:`fit_on_episodes`, :func:`calibrate_on_episodes`; :func:`validate_on_episodes`
  checks it on fresh ones).
- Sinks: :class:`MemorySink`, :class:`McapSink`; a failing sink warns and the loop goes on.
- :class:`AlarmCommand` runs a shell command of yours at each episode's first alarm.
- :class:`MonitorCallback` scores an SB3 model's training steps and logs them through SB3's logger.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from oodmon.monitor.alarm_command import AlarmCommand, AlarmCommandWarning
from oodmon.monitor.alarms import DEFAULT_CONSECUTIVE, AlarmEvent, AlarmTracker, episode_statistic
from oodmon.monitor.records import EpisodeRecord, RunInfo, StepRecord
from oodmon.monitor.scores import DEFAULT_SCORE, SCORES, score_function
from oodmon.monitor.sinks import FooterMemoryWarning, McapSink, MemorySink, RerunSink, Sink, SinkGroup, SinkWarning
from oodmon.monitor.stopping import Terminated, stop_on_sigterm
from oodmon.monitor.threshold import Threshold, calibrate

__all__ = [
    "CALIBRATION_SEED",
    "DEFAULT_CONSECUTIVE",
    "DEFAULT_SCORE",
    "SCORES",
    "AlarmCallback",
    "AlarmCommand",
    "AlarmCommandWarning",
    "AlarmEvent",
    "AlarmTracker",
    "EpisodeRecord",
    "ExplorationWarning",
    "FooterMemoryWarning",
    "LongerThanCalibrationWarning",
    "McapSink",
    "MemorySink",
    "Monitor",
    "MonitorCallback",
    "RerunSink",
    "MonitoredEnv",
    "NonFiniteObservationWarning",
    "OffCalibrationNoiseWarning",
    "OffCalibrationWarning",
    "OtherActionsWarning",
    "PolicyCannotAct",
    "RunInfo",
    "Sink",
    "SinkGroup",
    "SinkWarning",
    "StepRecord",
    "Stretches",
    "Terminated",
    "Threshold",
    "Validation",
    "calibrate",
    "calibrate_agent",
    "calibrate_on_episodes",
    "episode_statistic",
    "fit_on_episodes",
    "id_episode_scores",
    "load_records",
    "save_records",
    "score_function",
    "stop_on_sigterm",
    "validate_on_episodes",
    "validate_threshold",
    "watch_recorded",
]

# The parts that run a policy load torch and stable-baselines3; replay, which only reads logs and
# their records, should not pay for that. They load on first use.
_LAZY = {
    "AlarmCallback": "oodmon.monitor.monitor",
    "Monitor": "oodmon.monitor.monitor",
    "MonitoredEnv": "oodmon.monitor.monitored_env",
    "NonFiniteObservationWarning": "oodmon.monitor.monitor",
    "OffCalibrationNoiseWarning": "oodmon.monitor.monitor",
    "OffCalibrationWarning": "oodmon.monitor.monitor",
    "LongerThanCalibrationWarning": "oodmon.monitor.monitor",
    "PolicyCannotAct": "oodmon.monitor.monitor",
    "OtherActionsWarning": "oodmon.monitor.monitor",
    "CALIBRATION_SEED": "oodmon.monitor.calibration",
    "calibrate_agent": "oodmon.monitor.calibration",
    "id_episode_scores": "oodmon.monitor.calibration",
    "Stretches": "oodmon.monitor.threshold",
    "Validation": "oodmon.monitor.calibration",
    "validate_threshold": "oodmon.monitor.calibration",
    "MonitorCallback": "oodmon.monitor.sb3_callback",
    "ExplorationWarning": "oodmon.monitor.sb3_callback",
    "calibrate_on_episodes": "oodmon.monitor.recorded",
    "fit_on_episodes": "oodmon.monitor.recorded",
    "load_records": "oodmon.monitor.recorded",
    "save_records": "oodmon.monitor.recorded",
    "validate_on_episodes": "oodmon.monitor.recorded",
    "watch_recorded": "oodmon.monitor.recorded",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'oodmon.monitor' has no attribute {name!r}")
