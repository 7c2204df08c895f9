"""Steps per second scored by replay, beside a plain iteration over the same files' messages.

Run: .venv/bin/python benchmarks/replay_throughput.py

Writes 4 MCAP logs of 50,000 steps each (400 CartPole-like episodes of 500 steps, written by the
real McapSink from synthetic step records), then times, in this process:
- replay: ``read_log`` + ``compute_metrics`` (AUROC, AUPR, FPR@95, alarms, delays) of all files;
- plain: the stock ``mcap`` reader iterating over every message of the same files, no decoding.
The last line is ratio=<replay steps/s / plain steps/s>; goals: ratio >= 1 and >= 1,000,000 steps/s.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from oodmon.monitor import McapSink
from oodmon.monitor.records import EpisodeRecord, RunInfo, StepRecord
from oodmon.replay import compute_metrics, read_log

FILES, EPISODES_PER_FILE, LENGTH = 4, 100, 500


def write_logs(folder: Path) -> list[Path]:
    rng = np.random.default_rng(0)
    paths = []
    for index in range(FILES):
        shifted_run = index % 2 == 1
        variant, onset = ("cartpole:length=2.0", 100) if shifted_run else ("cartpole", 0)
        sink = McapSink(folder / f"log{index}.mcap")
        sink.open(RunInfo("cartpole", "ensemble", "chosen_std", 3.0, "score > 3 for 3 consecutive steps", "none", {}))
        for episode in range(EPISODES_PER_FILE):
            scores = rng.gamma(4.0, 0.5, LENGTH) + (np.arange(LENGTH) > onset) * (1.5 if shifted_run else 0.0)
            for step, score in enumerate(scores):
                sink.write_step(StepRecord(episode, step, int(step % 2), [90.0, 91.0], [score, score * 0.9],
                                           float(score), 3.0, bool(score > 3.0), bool(shifted_run and step > onset),
                                           [0.01, -0.02, 0.03, 0.0]))
            sink.end_episode(EpisodeRecord(episode, "oodmon/CartPole-v1", variant, onset, episode, 500.0, LENGTH, 0, None))
        sink.close()
        paths.append(folder / f"log{index}.mcap")
    return paths


def best_of(repeats: int, work) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        paths = write_logs(Path(folder))
        steps = FILES * EPISODES_PER_FILE * LENGTH

        def replay() -> None:
            compute_metrics([read_log(p) for p in paths])

        def plain() -> None:
            for path in paths:
                with open(path, "rb") as f:
                    for _ in make_reader(f).iter_messages():
                        pass

        replay_s, plain_s = best_of(3, replay), best_of(3, plain)
    print(f"steps in the logs                     {steps:12,d}")
    print(f"replay (read + all metrics)           {steps / replay_s:12,.0f} steps/s")
    print(f"plain iteration, stock mcap reader    {steps / plain_s:12,.0f} steps/s")
    print(f"ratio={plain_s / replay_s:.2f}")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
