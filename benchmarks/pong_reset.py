"""The cost of a seeded reset of oodmon's Pong beside a reset without a seed.

Run: .venv/bin/python benchmarks/pong_reset.py

Every episode the monitor, the calibration, the fitting and the bench play is seeded, so that one
seed fixes it. A reset without a seed is the game's own reset and the episode's 1..30 no-ops; a
seeded one draws the same and, before 2026-11-30, loaded the ROM again to seed the emulator's
generator (90 ms, some 60 agent steps' time), which draws nothing without sticky actions (the
paper's Pong has none). Both are timed in alternation (``timing.paired_us``), each seeded reset
with a seed of its own. The last line is ratio=<seeded reset / reset without a seed>; goal <= 1.2.
Measured 2026-11-30: seeded 95.2 ms, ratio=21.11 before; 4.8 ms, ratio=1.04 after.
"""

from __future__ import annotations

import argparse
import itertools

import gymnasium

import oodmon  # noqa: F401  (registers the envs)
from timing import paired_us  # benchmarks/timing.py, beside this script


def main() -> None:
    env = gymnasium.make("oodmon/Pong-v5")
    seeds = itertools.count()
    env.reset(seed=next(seeds))
    seeded_us, plain_us, ratio = paired_us(lambda: env.reset(seed=next(seeds)), env.reset, repeats=20)
    print(f"{'seeded reset':30s} {seeded_us / 1000:8.1f} ms")
    print(f"{'reset without a seed':30s} {plain_us / 1000:8.1f} ms")
    print(f"ratio={ratio:.2f}")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
