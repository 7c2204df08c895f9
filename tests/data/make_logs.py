"""Regenerates the small recorded logs that replay's tests read (tests/data/*.mcap).

Run: .venv/bin/python tests/data/make_logs.py

The shipped CartPole ensemble with a fixed threshold: 3 ID episodes, and 3 episodes of
cartpole:length=2.0 from step 100. The logs are committed so that replay and its numbers are
regression-tested without training or running an agent; regenerate them only on purpose
(a change of the log format), and update the pinned numbers in tests/replay/ with them.
"""

from __future__ import annotations

from pathlib import Path

from oodmon.agents import load
from oodmon.envs import Variant, parse_variant
from oodmon.monitor import McapSink, Monitor

HERE = Path(__file__).parent
THRESHOLD = 4.6


def main() -> None:
    agent = load("cartpole", "ensemble")
    for name, variant, onset in (("cartpole-ensemble-id", Variant("cartpole"), 0),
                                 ("cartpole-ensemble-length2", parse_variant("cartpole:length=2.0"), 100)):
        env = variant.make(onset_step=onset)
        with Monitor(agent, THRESHOLD, sinks=[McapSink(HERE / f"{name}.mcap", overwrite=True)]) as monitor:
            for episode in range(3):
                record = monitor.run_episode(env, seed=700 + episode, variant=variant.spec)
                print(name, record)


if __name__ == "__main__":
    main()
