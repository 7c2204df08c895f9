"""What judges afterwards: metrics, tables and regression checks from recorded MCAP logs.

Replay reads files only (logs from any machine and any earlier run); it never writes into them.
"""

from __future__ import annotations

from oodmon.replay.check import baseline_of, check_tolerance, find_falls, load_baseline
from oodmon.replay.metrics import (
    MonitorMetrics, VariantMetrics, alarm_events, compute_all_metrics, compute_metrics, compute_monitor_metrics,
    detectors_in, failed_episodes, fpr_at_tpr, made_from_episodes, pooled_fits, pooled_noise, pooled_thresholds,
    pooled_weights,
)
from oodmon.replay.failures import failure_step
from oodmon.replay.parts import MissingParts, missing_parts
from oodmon.replay.reader import (EpisodeLog, MissingPartWarning, NewerFormatWarning, RecoveryWarning, RunLog,
                                  SkippedLogWarning, read_log, read_logs)
from oodmon.replay.recalibrate import (ChangeInLogsWarning, LogEpisodes, LogStatistics, calibrate_from_logs,
                                      change_in_logs, episodes_from_logs, fit_detectors_from_logs, log_episodes)
from oodmon.replay.report import monitor_markdown, monitor_summary, monitor_table, to_csv, to_json, to_markdown, to_table

__all__ = [
    "ChangeInLogsWarning",
    "EpisodeLog",
    "LogEpisodes",
    "LogStatistics",
    "MissingPartWarning",
    "MissingParts",
    "MonitorMetrics",
    "NewerFormatWarning",
    "RecoveryWarning",
    "RunLog",
    "SkippedLogWarning",
    "VariantMetrics",
    "alarm_events",
    "baseline_of",
    "calibrate_from_logs",
    "change_in_logs",
    "check_tolerance",
    "compute_all_metrics",
    "compute_metrics",
    "compute_monitor_metrics",
    "detectors_in",
    "episodes_from_logs",
    "failed_episodes",
    "failure_step",
    "find_falls",
    "fit_detectors_from_logs",
    "fpr_at_tpr",
    "load_baseline",
    "log_episodes",
    "made_from_episodes",
    "missing_parts",
    "monitor_markdown",
    "monitor_summary",
    "monitor_table",
    "pooled_fits",
    "pooled_noise",
    "pooled_thresholds",
    "pooled_weights",
    "read_log",
    "read_logs",
    "to_csv",
    "to_json",
    "to_markdown",
    "to_table",
]
