"""Calibration episodes played side by side (``--workers``) beside one process.

Run: .venv/bin/python benchmarks/side_by_side.py [--task pong] [--method ensemble] [--episodes 10]

Times ``id_episode_scores`` (what ``oodmon calibrate`` and ``validate`` play) of a shipped agent
over the same episodes in one process and with ``workers`` = the cores (at most 2 here), one after
the other, best of two rounds each, torch and BLAS on one thread in both. The ensemble draws
nothing, so both give the same scores (checked: the script says ``same scores: True``). The last
line is ratio=<side by side / one process>; goal <= 0.6 on two cores (two processes, each a
copy of the agent, fork and collecting the results included).
Measured 2026-12-01 (AMD EPYC, two cores; Pong ensemble, 10 games): ratio=0.56 (9.04 s, 16.16 s).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from oodmon.agents import load
from oodmon.monitor import id_episode_scores
from oodmon.side_by_side import usable_cores
from oodmon.threads import set_threads


def timed(agent, episodes: int, workers: int) -> tuple[float, list[np.ndarray]]:
    best, scores = float("inf"), []
    for _ in range(2):
        start = time.perf_counter()
        scores = id_episode_scores(agent, episodes, workers=workers)
        best = min(best, time.perf_counter() - start)
    return best, scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pong")
    parser.add_argument("--method", default="ensemble")
    parser.add_argument("--episodes", type=int, default=10)
    args = parser.parse_args()
    set_threads(1)
    workers = min(usable_cores(), 2)
    agent = load(args.task, args.method)
    alone, one = timed(agent, args.episodes, 1)
    together, many = timed(agent, args.episodes, workers)
    same = len(one) == len(many) and all(np.array_equal(a, b) for a, b in zip(one, many))
    print(f"load average {os.getloadavg()[0]:.2f}; {args.task}/{args.method}, {args.episodes} episodes, "
          f"{sum(len(s) for s in one):,} steps")
    print(f"{'one process':30s} {alone:8.2f} s")
    print(f"{f'{workers} workers':30s} {together:8.2f} s")
    print(f"same scores: {same}")
    print(f"ratio={together / alone:.2f}")


if __name__ == "__main__":
    main()
