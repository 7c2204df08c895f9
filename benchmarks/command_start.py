"""Seconds of a command that plays no policy, from a new process's start: ``oodmon replay`` (its
table and ``--monitor``) and ``oodmon check`` of two small logs, ``oodmon envs``, and the
threshold's statistics, beside the same work with what they imported before 2026-12-04.

Run: .venv/bin/python benchmarks/command_start.py

Before 2026-12-04 every command imported torch (to set its threads; about a second; now those
that play no policy do not), replay imported the agents for the words of its episode uses, replay
and check ranked steps with ``sklearn.metrics`` (another second; now ``roc_points`` and
``average_precision`` in ``oodmon.replay.metrics``, the same numbers to the bit), check weighed
its delays with ``scipy.stats.mannwhitneyu`` (0.4 s; now ``mann_whitney_greater``), and every
command that calibrated, validated or benched imported ``scipy.stats`` for the binomial and Beta
functions of ``conformal_rank`` and ``clopper_pearson`` (0.6-0.7 s). Each case runs in a new
process, timed from its start (imports included) to its end, alternately with its "before": the
same code after importing what it imported then (torch and ``sklearn.metrics`` for replay and
check, ``scipy.stats`` too for check, torch for envs, ``scipy.stats`` for the statistics), which
is what those imports cost it. Five of each, the medians. Lines ``ratio_<case>=<now / before>``, and last ``ratio=`` the largest
(lower is better; goal <= 0.8: the imports saved stay saved). The logs are ``tests/data``'s (a
CartPole ensemble's five ID episodes and five of ``length=2.0``).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path
from statistics import median

from timing import print_ratios, process_seconds  # benchmarks/timing.py, beside this script

RUNS = 5
DATA = Path(__file__).resolve().parents[1] / "tests" / "data"
LOGS = [str(DATA / "cartpole-ensemble-id.mcap"), str(DATA / "cartpole-ensemble-length2.mcap")]
TIMED = """
import sys, time
start = time.perf_counter()
{before}
{work}
print(time.perf_counter() - start)
"""
CASES = {
    "replay": ("import torch, sklearn.metrics", "from oodmon.cli import main\n"
               "assert main(['replay', *sys.argv[1:3]]) == main(['replay', '--monitor', *sys.argv[1:3]]) == 0"),
    "check": ("import torch, sklearn.metrics, scipy.stats", "from oodmon.cli import main\nassert main(['check', *sys.argv[1:3], "
              "'--baseline', sys.argv[3]]) == 0"),
    "envs": ("import torch", "from oodmon.cli import main\nassert main(['envs', '--json']) == 0"),
    "threshold": ("import scipy.stats", "from oodmon.monitor.threshold import clopper_pearson, conformal_rank\n"
                                        "conformal_rank(50, 0.05, 0.9), clopper_pearson(3, 200)"),
}


def main() -> None:
    ratios = {}
    with tempfile.TemporaryDirectory() as folder:
        baseline = str(Path(folder) / "baseline.json")
        subprocess.run([sys.executable, "-m", "oodmon", "check", *LOGS, "--baseline", baseline, "--update"],
                       capture_output=True, check=True)
        for case, (before, work) in CASES.items():
            now, then = [], []
            for _ in range(RUNS):
                now.append(process_seconds(TIMED.format(before="", work=work), *LOGS, baseline))
                then.append(process_seconds(TIMED.format(before=before, work=work), *LOGS, baseline))
            print(f"{case:10s} {median(now):6.2f} s   with {before!r} first {median(then):6.2f} s")
            ratios[case] = median(now) / median(then)
    print_ratios("ratio", ratios)


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
