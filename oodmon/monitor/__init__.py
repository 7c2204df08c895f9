"""What watches: per-step uncertainty scores, calibrated thresholds, alarms, MCAP and Rerun sinks.

Not built yet: see the monitor issue.
"""

__all__: list[str] = []
