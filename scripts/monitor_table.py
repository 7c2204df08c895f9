"""docs/bench.md's tables of the monitor's own benchmark, from the committed results in results/monitor/.

Run: .venv/bin/python scripts/monitor_table.py

Each results/monitor/<task>.json is the output of
`oodmon bench --protocol monitor --task <task> --trials 1 --json` (the commands are in
results/monitor/README.md): the shipped agents, the task's best detector, 200 fresh ID episodes and
10 episodes per failing variant, each shifting at a random onset. One row per agent: the false-alarm
rate with its 95% Clopper-Pearson interval, the share of failing episodes alarmed before the
failure and the warning they had (the lead: steps from the alarm to the failure, median and
range; files made before the lead was recorded leave it blank), and the delays from the onset
over all alarmed shifted episodes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "results" / "monitor"


def table(task: str) -> str:
    data = json.loads((RESULTS / f"{task}.json").read_text())
    rows = {(m["method"], m["variant"]): m for m in data["alarms"]}
    lines = ["| agent | false alarms (ID) [95% interval] | alarmed before failure | lead median [range] "
             "| shifted episodes alarmed | delay median / p90 |", "|---|---|---|---|---|---|"]
    for method in sorted({m for m, _ in rows}):
        ident, pooled = rows[(method, task)], rows[(method, "all shifted")]
        before = (f"{pooled['before_failure']}/{pooled['failed']} ({pooled['before_failure'] / pooled['failed']:.0%})"
                  if pooled["failed"] else "no failure")
        leads = pooled.get("leads") or []
        lead = f"{pooled['lead_median']:g} [{min(leads)}, {max(leads)}]" if leads else ""
        lines.append(
            f"| {task}-{method} | {ident['false_alarms']}/{ident['episodes']} ({ident['false_alarm_rate']:.1%}) "
            f"[{ident['far_low']:.1%}, {ident['far_high']:.1%}] | {before} | {lead} | "
            f"{pooled['alarmed']}/{pooled['episodes'] - pooled.get('never_shifted', 0)} | "  # (files before 2026-12-01 lack it)
            f"{pooled['delay_median']:g} / {pooled['delay_p90']:g} |")
    return "\n".join(lines)


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    for task in ("cartpole", "pendulum", "pong"):
        if (RESULTS / f"{task}.json").exists():
            print(f"{task}:\n\n{table(task)}\n")
