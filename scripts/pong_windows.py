"""Replay the Pong monitor benchmark's logs under longer alarm windows (docs/pong.md).

Run: .venv/bin/python scripts/pong_windows.py METHOD [LOG_ROOT]

LOG_ROOT defaults to runs/bench-monitor/logs, where
`oodmon bench --protocol monitor --task pong --methods METHOD --all-variants ...` (the command in
results/monitor/README.md) wrote its logs with the default window 1. For each window w, a game's
statistic is the largest mean of w consecutive `features` scores; the first 90 ID games calibrate
(the threshold is the largest of their statistics, as the bench's confidence-0.99 rule does with
90 games), the other 110 give the false alarms, and each shifted game is alarmed at the first
step from its onset where the w-step mean passes the threshold.
"""

from __future__ import annotations

import argparse
import glob

import numpy as np

from oodmon.names import METHODS
from oodmon.replay import read_log


def window_means(scores: np.ndarray, w: int) -> np.ndarray:
    if len(scores) < w:
        return np.array([-np.inf])
    sums = np.cumsum(np.r_[0.0, scores])
    return (sums[w:] - sums[:-w]) / w


def main(method: str, root: str = "runs/bench-monitor/logs") -> None:
    # The bench's folder names hold "-w<N>" for any window but 1.
    folders = [f for f in glob.glob(f"{root}/pong-*/{method}/trial0/monitor") if "-w" not in f.split("/")[-4]]
    if not folders:
        raise SystemExit(f"no window-1 Pong logs of {method} under {root}")
    logs = {path.split("/")[-1][:-5]: read_log(path) for path in sorted(glob.glob(folders[0] + "/*.mcap"))}
    ident = logs.pop("pong")
    for w in (1, 20, 50, 100, 200):
        stats = np.array([window_means(e.scores_of("features"), w).max() for e in ident.episodes])
        threshold = stats[:90].max()
        alarmed, delays = {}, []
        for name, log in logs.items():
            hits = 0
            for e in log.episodes:
                above = np.nonzero(window_means(e.scores_of("features"), w) > threshold)[0] + w - 1
                after = above[above >= e.onset]
                if len(after):
                    hits += 1
                    delays.append(int(after[0] - e.onset))
            alarmed[name.replace("pong_", "")] = hits
        total = sum(len(log.episodes) for log in logs.values())
        print(f"window {w}: threshold {threshold:.1f}; false alarms {int((stats[90:] > threshold).sum())}/"
              f"{len(stats) - 90} ID games; {sum(alarmed.values())}/{total} shifted games alarmed, median delay "
              f"{np.median(delays) if delays else float('nan'):g} decisions; per variant {alarmed}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("method", choices=METHODS, help="the Pong agent benched")
    parser.add_argument("root", nargs="?", default="runs/bench-monitor/logs", help="the bench's logs (default %(default)s)")
    args = parser.parse_args()
    main(args.method, args.root)
