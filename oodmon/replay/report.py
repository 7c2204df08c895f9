"""Metrics as a terminal table, JSON, CSV or Markdown."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence

from rich.table import Table

from oodmon.replay.metrics import VariantMetrics

__all__ = ["COLUMNS", "to_csv", "to_json", "to_markdown", "to_table"]

#: (field, heading) in the order the reports show them.
COLUMNS = [
    ("task", "task"), ("method", "method"), ("detector", "detector"), ("variant", "variant"), ("episodes", "episodes"),
    ("steps", "steps"),
    ("auroc", "AUROC"), ("aupr", "AUPR"), ("fpr_at_95_tpr", "FPR@95TPR"), ("false_alarm_rate", "false alarms (ID)"),
    ("early_alarm_rate", "early alarms"), ("detection_rate", "detected"), ("delay_mean", "delay mean"),
    ("delay_median", "delay median"),
]


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


def to_table(metrics: Sequence[VariantMetrics], title: str = "replay") -> Table:
    table = Table(title=title)
    for name, heading in COLUMNS:
        table.add_column(heading, justify="left" if name in ("task", "method", "detector", "variant") else "right")
    for m in metrics:
        table.add_row(*(_cell(getattr(m, name)) for name, _ in COLUMNS))
    return table


def to_json(metrics: Sequence[VariantMetrics]) -> str:
    return json.dumps([m.to_dict() for m in metrics], indent=1)


def to_csv(metrics: Sequence[VariantMetrics]) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow([name for name, _ in COLUMNS])
    for m in metrics:
        writer.writerow(["" if getattr(m, name) is None else getattr(m, name) for name, _ in COLUMNS])
    return buffer.getvalue()


def to_markdown(metrics: Sequence[VariantMetrics]) -> str:
    lines = ["| " + " | ".join(h for _, h in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(_cell(getattr(m, name)) for name, _ in COLUMNS) + " |" for m in metrics]
    return "\n".join(lines) + "\n"
