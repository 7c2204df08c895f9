"""Regression checks over recorded logs: metrics against a baseline file.

The baseline is JSON: ``{"tolerance": 0.02, "metrics": {"task/method/variant": {name: value}}}``.
A metric *falls* when it moves the wrong way by more than the tolerance: AUROC, AUPR and the
detection rate going down; the FPR at 95% TPR, the false-alarm rates and the mean delay going
up (delays by more than the tolerance times their baseline, since they count steps).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from oodmon.errors import ConfigError
from oodmon.jsonfile import read_json
from oodmon.replay.metrics import VariantMetrics

__all__ = ["HIGHER_IS_BETTER", "LOWER_IS_BETTER", "baseline_of", "check_tolerance", "compare_metrics", "find_falls",
           "load_baseline"]

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
    """Read and check a baseline file (see the module docstring).

    Raises:
        ConfigError: the file is missing, not JSON, or not a baseline: every metric must be a known
            name with a finite number, the tolerance a number >= 0.
    """
    path = Path(path)
    data = read_json(path, name="baseline", missing=f"write one with `oodmon check LOGS --baseline {path} --update`",
                     folder="give the JSON file `oodmon check --update` wrote")
    if not isinstance(data, dict) or not isinstance(data.get("metrics"), dict):
        got = data.get("metrics") if isinstance(data, dict) else data
        raise ConfigError(f"{path} is not an oodmon baseline: 'metrics' must be an object of rows, not {got!r:.40}")
    known = HIGHER_IS_BETTER + LOWER_IS_BETTER
    for key, row in data["metrics"].items():
        if not isinstance(row, dict):
            raise ConfigError(f"{path}: metrics[{key!r}]={row!r:.40} is not allowed; each row maps metric names to numbers")
        for name, value in row.items():
            if name not in known:
                raise ConfigError(f"{path}: metrics[{key!r}] has unknown metric {name!r}; known: {', '.join(known)}")
            if not _is_number(value):
                raise ConfigError(f"{path}: metrics[{key!r}][{name!r}]={value!r:.40} is not allowed; give a finite number")
    if "tolerance" in data:
        check_tolerance(data["tolerance"], f"{path}: tolerance")
    return data


def check_tolerance(value: object, name: str = "tolerance") -> float:
    """``value`` as a float if it is a finite number >= 0, else :class:`ConfigError`."""
    if not _is_number(value) or value < 0:
        raise ConfigError(f"{name}={value!r} is not allowed; give a finite number >= 0 (the allowed fall)")
    return float(value)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def find_falls(metrics: Sequence[VariantMetrics], baseline: dict, tolerance: float | None = None) -> list[str]:
    """One line per metric that fell below its baseline by more than the tolerance, or went missing."""
    tolerance = baseline.get("tolerance", 0.02) if tolerance is None else tolerance
    current = {m.key: {name: getattr(m, name) for name in HIGHER_IS_BETTER + LOWER_IS_BETTER} for m in metrics}
    return compare_metrics(current, baseline["metrics"], tolerance, what="the logs")


def compare_metrics(current: dict[str, dict[str, float | None]], expected: dict[str, dict[str, float]],
                    tolerance: float, *, what: str = "the new results", relative: Sequence[str] = ("delay_mean",),
                    higher: Sequence[str] = HIGHER_IS_BETTER) -> list[str]:
    """One line per metric of ``expected`` (rows of ``{name: value}`` by key) that ``current``
    lacks or that moved the wrong way by more than ``tolerance``: names in ``higher`` may not fall,
    every other name may not rise, those in ``relative`` (delays and leads, counted in steps) by
    more than ``tolerance`` times their baseline value. Shared by ``oodmon check`` (logs) and
    ``bench --baseline``."""
    falls = []
    for key, row in sorted(expected.items()):
        if key not in current:
            falls.append(f"{key}: missing from {what} (the baseline has it)")
            continue
        for name, was in row.items():
            now = current[key].get(name)
            if now is None:
                falls.append(f"{key}: {name} is missing (baseline {was:.4g})")
            elif name in higher:
                if now < (was * (1 - tolerance) if name in relative else was - tolerance):
                    falls.append(f"{key}: {name} fell from {was:.4g} to {now:.4g} (tolerance {tolerance})")
            else:
                allowed = was * (1 + tolerance) if name in relative else was + tolerance
                if now > allowed:
                    falls.append(f"{key}: {name} rose from {was:.4g} to {now:.4g} (tolerance {tolerance})")
    return falls
