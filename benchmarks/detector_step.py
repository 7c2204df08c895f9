"""A monitored CartPole step with every detector beside the same step with the spread alone.

Run: .venv/bin/python benchmarks/detector_step.py

Both: the shipped CartPole ensemble (K=5) under the Monitor, writing an MCAP log, on the same
ID episodes, one thread for torch and numpy's BLAS. "All": its shipped detectors (spread, dynamics, features,
combined; `bash scripts/fit_zoo_detectors.sh` makes them). The last line is
ratio=<all-detector step time / spread-only step time>; goal <= 1.5.

The two run in pairs of one episode each, back to back (which one first alternates), 30 pairs;
the ratio is the median of the pairs' ratios. On a shared VM the machine's speed changes by
20-60% from one second to the next: a pair sees one state of it, while the best round of each
kind may come from different states (the best-of-rounds ratio, printed too, read 1.25-1.67 in
one quarter of an hour where the pairs' median read 1.47-1.48).

Before the ratio it prints where an all-detector step's time goes: the median time of each
detector's score() and of the MCAP sink's write_step(), each timed in the loop (in episodes of
their own, after the pairs: the timers do not touch the pairs' steps). A detector costs more in
the loop than called alone again and again (the dynamics detector 20.5-21 us against 14-15, the
features detector 9 against 5.5, measured here): between two of its calls the caches and branch
predictors serve the rest of the step, the policy's 1.35 MB of weights among it.

Then what each detector adds to the step on its own: the same pairs (10 of them) with every
learned detector but one answering a constant (its score() replaced, so the monitor, the records
and the log are the same as with all of them), printed as ``alone <name>: <ratio>``, and with all
of them answering constants (``alone none``: what scoring and logging three more scores costs).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from oodmon.agents import load
from oodmon.envs import Variant
from oodmon.monitor import McapSink, Monitor
from oodmon.monitor.detectors import detectors_for
from oodmon.threads import set_threads

EPISODES = 1
PAIRS = 30


def seconds_per_step(agent, detectors, sink: McapSink, episodes: int = EPISODES) -> float:
    env = Variant("cartpole").make()
    with Monitor(agent, threshold=1e9, detectors=detectors, sinks=[sink]) as monitor:
        steps, start = 0, time.perf_counter()
        for episode in range(episodes):
            steps += monitor.run_episode(env, seed=episode).length
        return (time.perf_counter() - start) / steps


@contextmanager
def scores_replaced(replacements: dict):
    """Each detector's score() replaced by its function here (an instance attribute), put back after."""
    for detector, score in replacements.items():
        detector.score = score
    try:
        yield
    finally:
        for detector in replacements:
            del detector.score


def in_loop_us(agent, detectors, folder: Path, episodes: int = 3) -> dict[str, float]:
    """Median microseconds of each detector's score() and of the sink's write_step() in the loop."""
    times: dict[str, list[int]] = {name: [] for name in (*detectors.names, "MCAP sink")}

    def timed(call, name):
        def wrapper(*args):
            start = time.perf_counter_ns()
            result = call(*args)
            times[name].append(time.perf_counter_ns() - start)
            return result
        return wrapper

    sink = McapSink(folder / "timed.mcap")
    sink.write_step = timed(sink.write_step, "MCAP sink")
    with scores_replaced({detector: timed(detector.score, detector.name) for detector in detectors}):
        seconds_per_step(agent, detectors, sink, episodes)
    return {name: float(np.median(values)) / 1e3 for name, values in times.items()}


def paired_ratio(agent, detectors, log: Path, pairs: int = PAIRS) -> tuple[np.ndarray, np.ndarray]:
    """Seconds per step of the spread alone and of ``detectors``, in ``pairs`` back-to-back pairs."""
    spread, every = [], []
    for pair in range(pairs):
        runs = [(spread, None), (every, detectors)]
        for times, chosen in runs if pair % 2 == 0 else runs[::-1]:
            times.append(seconds_per_step(agent, chosen, McapSink(log, overwrite=True)))
    return np.array(spread), np.array(every)


def alone_ratios(agent, detectors, log: Path, pairs: int = 10) -> dict[str, float]:
    """The paired ratio with each learned detector computing and the others answering a constant
    (``none``: all of them constant)."""
    learned = [d for d in detectors if d.name != "spread"]
    ratios = {}
    for kept in [*(d.name for d in learned), "none"]:
        with scores_replaced({detector: lambda context: 1.0 for detector in learned if detector.name != kept}):
            spread, every = paired_ratio(agent, detectors, log, pairs)
        ratios[kept] = float(np.median(every / spread))
    return ratios


def main() -> None:
    set_threads(1)  # torch and numpy's BLAS, as every oodmon command
    agent = load("cartpole", "ensemble")
    detectors = detectors_for(agent)
    if detectors is None:
        raise SystemExit("the zoo's CartPole ensemble has no fitted detectors: run bash scripts/fit_zoo_detectors.sh")
    with tempfile.TemporaryDirectory() as folder:
        log = Path(folder) / "run.mcap"
        seconds_per_step(agent, detectors, McapSink(log, overwrite=True), 1)  # warm-up: imports, first calls
        spread, every = paired_ratio(agent, detectors, log)
        parts = in_loop_us(agent, detectors, Path(folder))
        alone = alone_ratios(agent, detectors, log)
    print("in the loop, median us: " + ", ".join(f"{name} {value:.1f}" for name, value in parts.items()))
    print("alone " + ", ".join(f"{name}: {value:.2f}" for name, value in alone.items()))
    print(f"spread only                             {np.median(spread) * 1e6:8.1f} us/step "
          f"(median; best {spread.min() * 1e6:.1f})")
    print(f"{', '.join(detectors.names):40s}{np.median(every) * 1e6:8.1f} us/step (median; best {every.min() * 1e6:.1f})")
    print(f"best of each: {every.min() / spread.min():.2f}")
    print(f"ratio={np.median(every / spread):.2f}")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
