"""Per-episode alarm statistics of many fresh ID episodes of a shipped agent, computed once.

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/id_episode_statistics.py [--episodes 1200]

Writes results/calibration/cartpole-ensemble-id.json: for each detector the shipped CartPole
ensemble has (spread, dynamics, features, combined), the statistic under the default alarm rule
(m = 3 consecutive steps, window 1) of each of the episodes, seeds 700,000 + i (the validation
range, apart from calibration's). An episode alarms under a threshold exactly when its statistic
exceeds it, so re-drawing calibration sets from these episodes and checking each threshold on the
rest measures what a threshold's false-alarm rate is, without playing the episodes again
(tests/monitor/test_rule_and_calibration.py does it 100 times in a fraction of a second).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from oodmon import seeds
from oodmon.agents import load
from oodmon.envs import Variant
from oodmon.monitor import DEFAULT_CONSECUTIVE, Monitor, episode_statistic
from oodmon.monitor.detectors import detectors_for


class StatisticSink:
    """Keeps the steps of the running episode only; at its end, each detector's statistic."""

    def __init__(self, names: list[str]) -> None:
        self.names, self.steps = names, []
        self.statistics: dict[str, list[float]] = {name: [] for name in names}
        self.lengths: list[int] = []

    def open(self, run) -> None: ...
    def write_alarm(self, event) -> None: ...
    def close(self) -> None: ...

    def write_step(self, record) -> None:
        self.steps.append(record.scores)

    def end_episode(self, record) -> None:
        for name in self.names:
            scores = np.array([step[name] for step in self.steps])
            self.statistics[name].append(float(episode_statistic(scores, DEFAULT_CONSECUTIVE, 1)))
        self.lengths.append(len(self.steps))
        self.steps = []

OUT = Path(__file__).resolve().parents[1] / "results" / "calibration" / "cartpole-ensemble-id.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1200)
    args = parser.parse_args()
    agent = load("cartpole", "ensemble")
    detectors = detectors_for(agent)
    env = Variant("cartpole").make()
    started = time.perf_counter()
    sink = StatisticSink(detectors.names)
    with Monitor(agent, detectors=detectors, sinks=[sink], log_observations=False) as monitor:
        for episode in range(args.episodes):
            monitor.run_episode(env, seed=seeds.VALIDATION + episode, variant="cartpole")
            if (episode + 1) % 100 == 0:
                print(f"{episode + 1}/{args.episodes} episodes, {time.perf_counter() - started:.0f} s", flush=True)
    env.close()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({
        "agent": "cartpole-ensemble", "rule": {"consecutive": DEFAULT_CONSECUTIVE, "window": 1},
        "seeds": [seeds.VALIDATION, seeds.VALIDATION + args.episodes], "episode_lengths": sink.lengths,
        "statistics": {name: [round(v, 6) for v in values] for name, values in sink.statistics.items()},
        "command": "OODMON_TORCH_THREADS=1 .venv/bin/python scripts/id_episode_statistics.py --episodes "
                   f"{args.episodes}",
    }) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
