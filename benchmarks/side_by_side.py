"""Calibration or fitting episodes played side by side (``--workers``) beside one process.

Run: .venv/bin/python benchmarks/side_by_side.py [--task pong] [--method ensemble] [--episodes 10] [--fitting]

Times ``id_episode_scores`` (what ``oodmon calibrate`` and ``validate`` play) of a shipped agent
over the same episodes in one process and with ``workers`` = the cores (at most 2 here), one after
the other, best of two rounds each, torch and BLAS on one thread in both. The ensemble draws
nothing, so both give the same scores (checked: the script says ``same scores: True``). The last
line is ratio=<side by side / one process>; goal <= 0.6 on two cores (two processes, each a
copy of the agent, fork and collecting the results included).
Measured 2026-12-01 (AMD EPYC, two cores; Pong ensemble, 10 games): ratio=0.56 (9.04 s, 16.16 s).

``--fitting``: the detectors' fitting episodes instead (``collect``, what ``oodmon fit-detectors``
plays), each game sent back whole with its frames, the estimates of the last third kept as the
fitting keeps them; the same frames and actions checked. Measured 2026-12-01 (the same machine;
Pong ensemble, 10 games): ratio=0.58 (10.20 s, 17.68 s). Once each worker had a pipe of its own
instead of a process pool's (``oodmon.side_by_side``): 0.52 (9.14 s, 17.45 s) and, ``--fitting``,
0.55 (10.27 s, 18.56 s).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from oodmon.agents import load
from oodmon.monitor import id_episode_scores
from oodmon.monitor.detectors import collect
from oodmon.side_by_side import usable_cores
from oodmon.threads import set_threads


def timed(agent, episodes: int, workers: int, fitting: bool) -> tuple[float, list[np.ndarray]]:
    """The best of two rounds' seconds, and what the last round played: each episode's scores, or
    (fitting) its observations and actions."""
    best, played = float("inf"), []
    for _ in range(2):
        start = time.perf_counter()
        if fitting:
            env = agent.make_env()
            played = [array for t in collect(agent, env, episodes, workers=workers, estimates_from=2 * episodes // 3)
                      for array in (t.observations, t.actions)]
            env.close()
        else:
            played = id_episode_scores(agent, episodes, workers=workers)
        best = min(best, time.perf_counter() - start)
    return best, played


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pong")
    parser.add_argument("--method", default="ensemble")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--fitting", action="store_true", help="the detectors' fitting episodes (collect)")
    args = parser.parse_args()
    set_threads(1)
    workers = min(usable_cores(), 2)
    agent = load(args.task, args.method)
    alone, one = timed(agent, args.episodes, 1, args.fitting)
    together, many = timed(agent, args.episodes, workers, args.fitting)
    same = len(one) == len(many) and all(np.array_equal(a, b) for a, b in zip(one, many))
    steps = sum(len(a) for a in (one[1::2] if args.fitting else one))
    print(f"load average {os.getloadavg()[0]:.2f}; {args.task}/{args.method}, {args.episodes} "
          f"{'fitting' if args.fitting else 'calibration'} episodes, {steps:,} steps")
    print(f"{'one process':30s} {alone:8.2f} s")
    print(f"{f'{workers} workers':30s} {together:8.2f} s")
    print(f"same {'frames and actions' if args.fitting else 'scores'}: {same}")
    print(f"ratio={together / alone:.2f}")


if __name__ == "__main__":
    main()
