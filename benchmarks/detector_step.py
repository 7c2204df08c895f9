"""A monitored CartPole step with every detector beside the same step with the spread alone.

Run: .venv/bin/python benchmarks/detector_step.py

Both: the shipped CartPole ensemble (K=5) under the Monitor, writing an MCAP log, on the same
ID episodes, one torch thread. "All": its shipped detectors (spread, dynamics, features,
combined; `bash scripts/fit_zoo_detectors.sh` makes them). The last line is
ratio=<all-detector step time / spread-only step time>; goal <= 1.5.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import torch

from oodmon.agents import load
from oodmon.envs import Variant
from oodmon.monitor import McapSink, Monitor
from oodmon.monitor.detectors import detectors_for

EPISODES = 2
ROUNDS = 20


def seconds_per_step(agent, detectors, folder: Path, episodes: int = EPISODES) -> float:
    env = Variant("cartpole").make()
    with Monitor(agent, threshold=1e9, detectors=detectors, sinks=[McapSink(folder / "run.mcap")]) as monitor:
        steps, start = 0, time.perf_counter()
        for episode in range(episodes):
            steps += monitor.run_episode(env, seed=episode).length
        return (time.perf_counter() - start) / steps


def main() -> None:
    torch.set_num_threads(1)
    agent = load("cartpole", "ensemble")
    detectors = detectors_for(agent)
    if detectors is None:
        raise SystemExit("the zoo's CartPole ensemble has no fitted detectors: run bash scripts/fit_zoo_detectors.sh")
    spread = every = float("inf")
    with tempfile.TemporaryDirectory() as folder:
        seconds_per_step(agent, detectors, Path(folder), 1)  # warm-up: imports, first calls
        for _ in range(ROUNDS):  # interleaved, best of each: the rounds least disturbed by the machine
            spread = min(spread, seconds_per_step(agent, None, Path(folder)))
            every = min(every, seconds_per_step(agent, detectors, Path(folder)))
    print(f"spread only                             {spread * 1e6:8.1f} us/step")
    print(f"{', '.join(detectors.names):40s}{every * 1e6:8.1f} us/step")
    print(f"ratio={every / spread:.2f}")


if __name__ == "__main__":
    main()
