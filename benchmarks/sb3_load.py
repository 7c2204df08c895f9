"""Seconds from a new process's start to your SB3 model loaded by oodmon, beside SB3's own load.

Run: .venv/bin/python benchmarks/sb3_load.py

What every ``oodmon ... --sb3 ZIP`` command pays before its first step: a new Python process
imports oodmon and loads the file with ``oodmon.agents.sb3.load_sb3`` (its restricted reading of
the pickled parts, then SB3's ``load``); the plain thing is a process that imports
stable-baselines3 and calls the algorithm's ``load``. Untrained PPO (CartPole-v1) and SAC
(Pendulum-v1) models, saved once; each process timed from its start (its imports included) to
the loaded model, alternately, five of each; the medians. The last line is
ratio=<the larger of oodmon's / SB3's>; goal <= 1.0. Measured 2026-11-30, before SB3's load built
the model's optimizers without importing torch._dynamo: PPO 2.41 s against 2.34 s, SAC 2.39 against
2.29, ratio=1.04; after: PPO 1.35 s against 2.25 s, SAC 1.43 s against 2.47 s, ratio=0.60.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from statistics import median

import gymnasium
from stable_baselines3 import PPO, SAC

from timing import process_seconds  # benchmarks/timing.py, beside this script

RUNS = 5
OURS = """
import sys, time
start = time.perf_counter()
from oodmon.agents.sb3 import load_sb3
load_sb3([sys.argv[1]], sys.argv[2])
print(time.perf_counter() - start)
"""
THEIRS = """
import sys, time
start = time.perf_counter()
import stable_baselines3
getattr(stable_baselines3, sys.argv[3]).load(sys.argv[1], device="cpu")
print(time.perf_counter() - start)
"""


def main() -> None:
    ratios = {}
    with tempfile.TemporaryDirectory() as folder:
        for algorithm, env_id in ((PPO, "CartPole-v1"), (SAC, "Pendulum-v1")):
            path = str(Path(folder) / f"{algorithm.__name__}.zip")
            algorithm("MlpPolicy", gymnasium.make(env_id), seed=0).save(path)
            ours, theirs = [], []
            for _ in range(RUNS):
                ours.append(process_seconds(OURS, path, env_id))
                theirs.append(process_seconds(THEIRS, path, env_id, algorithm.__name__))
            name = algorithm.__name__
            print(f"{name:4s} oodmon load_sb3 {median(ours):6.2f} s   SB3 {name}.load {median(theirs):6.2f} s")
            ratios[name] = median(ours) / median(theirs)
            print(f"ratio_{name.lower()}={ratios[name]:.2f}")
    print(f"ratio={max(ratios.values()):.2f}")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
