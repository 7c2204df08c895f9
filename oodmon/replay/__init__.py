"""What judges afterwards: metrics, tables and regression checks from recorded MCAP logs.

Replay reads files only (logs from any machine and any earlier run); it never writes into them.
"""

from __future__ import annotations

from oodmon.replay.check import baseline_of, check_tolerance, find_falls, load_baseline
from oodmon.replay.metrics import (
    VariantMetrics, alarm_events, compute_all_metrics, compute_metrics, detectors_in, fpr_at_tpr,
)
from oodmon.replay.reader import EpisodeLog, RecoveryWarning, RunLog, SkippedLogWarning, read_log, read_logs
from oodmon.replay.report import to_csv, to_json, to_markdown, to_table

__all__ = [
    "EpisodeLog",
    "RecoveryWarning",
    "RunLog",
    "SkippedLogWarning",
    "VariantMetrics",
    "alarm_events",
    "baseline_of",
    "check_tolerance",
    "compute_all_metrics",
    "compute_metrics",
    "detectors_in",
    "find_falls",
    "fpr_at_tpr",
    "load_baseline",
    "read_log",
    "read_logs",
    "to_csv",
    "to_json",
    "to_markdown",
    "to_table",
]
