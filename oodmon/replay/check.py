"""Regression checks over recorded logs: metrics against a baseline file.

The baseline is JSON: ``{"tolerance": 0.02, "metrics": {"task/method/variant": {name: value}}}``.
A metric *falls* when it moves the wrong way by more than the tolerance: AUROC, AUPR and the
detection rate going down; the FPR at 95% TPR, the false-alarm rates and the mean delay going
up (delays by more than the tolerance times their baseline, since they count steps).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from oodmon.errors import ConfigError
from oodmon.replay.metrics import VariantMetrics

__all__ = ["HIGHER_IS_BETTER", "LOWER_IS_BETTER", "baseline_of", "find_falls", "load_baseline"]

HIGHER_IS_BETTER = ("auroc", "aupr", "detection_rate")
LOWER_IS_BETTER = ("fpr_at_95_tpr", "false_alarm_rate", "early_alarm_rate", "delay_mean")


def baseline_of(metrics: Sequence[VariantMetrics], tolerance: float) -> dict:
    """The baseline that ``metrics`` would write (``oodmon check --update``)."""
    return {
        "tolerance": tolerance,
        "metrics": {m.key: {name: getattr(m, name) for name in HIGHER_IS_BETTER + LOWER_IS_BETTER
                            if getattr(m, name) is not None} for m in metrics},
    }


def load_baseline(path: str | Path) -> dict:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"baseline {path} does not exist; write one with `oodmon check LOGS --baseline {path} --update`") from None
    except json.JSONDecodeError as error:
        raise ConfigError(f"baseline {path} is not valid JSON ({error})") from None
    if not isinstance(data, dict) or "metrics" not in data:
        raise ConfigError(f"{path} is not an oodmon baseline (no 'metrics')")
    return data


def find_falls(metrics: Sequence[VariantMetrics], baseline: dict, tolerance: float | None = None) -> list[str]:
    """One line per metric that fell below its baseline by more than the tolerance, or went missing."""
    tolerance = baseline.get("tolerance", 0.02) if tolerance is None else tolerance
    current = {m.key: m for m in metrics}
    falls = []
    for key, expected in sorted(baseline["metrics"].items()):
        if key not in current:
            falls.append(f"{key}: missing from the logs (the baseline has it)")
            continue
        for name, was in expected.items():
            now = getattr(current[key], name, None)
            if now is None:
                falls.append(f"{key}: {name} is missing (baseline {was:.4g})")
            elif name in HIGHER_IS_BETTER and now < was - tolerance:
                falls.append(f"{key}: {name} fell from {was:.4g} to {now:.4g} (tolerance {tolerance})")
            elif name in LOWER_IS_BETTER:
                allowed = was * (1 + tolerance) if name == "delay_mean" else was + tolerance
                if now > allowed:
                    falls.append(f"{key}: {name} rose from {was:.4g} to {now:.4g} (tolerance {tolerance})")
    return falls
