"""The dynamics model's fit: microseconds per Adam update, and its batch gather beside advanced indexing.

Run: .venv/bin/python benchmarks/dynamics_fit.py

The fit (``DynamicsDetector.fit``) draws each update's batch, 5 members x 512 transitions, out of
the fitting transitions. Since 2026-12-02 it picks the rows with ``index_select`` along dim 0
instead of advanced indexing (``xs[index]``): the same numbers (the fitted weights the same bytes,
the shipped CartPole ensemble's detectors refitted to the same file), in a third to a half of the
time (ratio 0.31, 0.40 and 0.49 in three runs, 2026-12-02; a fit 4% faster). It
prints the fit's time per update on 10,000 synthetic transitions of CartPole's size (4 readings,
2 actions; 30 epochs, 600 updates, best of 3 fits), the two gathers' times on 45,000 transitions
(the default fit of your own env) and last ``ratio=<index_select gather / advanced-index gather>``
(lower is better; goal <= 0.6). One thread.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from oodmon.monitor.detectors.base import Trajectory
from oodmon.monitor.detectors.dynamics import DynamicsDetector
from oodmon.threads import set_threads
from timing import per_call_us  # benchmarks/timing.py, beside this script


def synthetic_episodes(episodes: int = 20, steps: int = 500, readings: int = 4) -> list[Trajectory]:
    """Random-walk episodes of CartPole's size, two actions: what the fit's cost depends on."""
    rng = np.random.default_rng(0)
    return [Trajectory(observations=np.cumsum(rng.standard_normal((steps + 1, readings)), 0).astype(np.float32) * 0.1,
                       actions=rng.integers(0, 2, steps)) for _ in range(episodes)]


def fit_us_per_update(trajectories: list[Trajectory], epochs: int = 30, fits: int = 3) -> float:
    best = float("inf")
    for _ in range(fits):
        detector = DynamicsDetector(2, seed=0, epochs=epochs)
        start = time.perf_counter()
        detector.fit(trajectories)
        best = min(best, time.perf_counter() - start)
    updates = epochs * -(-sum(len(t.actions) for t in trajectories) // detector.batch_size)
    return best / updates * 1e6


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    set_threads(1)
    print(f"{'fit, per update (10,000 transitions, 5 members, batch 512)':64s} {fit_us_per_update(synthetic_episodes()):8.1f} us")
    generator = torch.Generator().manual_seed(0)
    xs = torch.randn(45_000, 6, generator=generator)
    index = torch.randint(0, len(xs), (5, 512), generator=generator)
    rows = index.reshape(-1)
    assert torch.equal(xs[index], xs.index_select(0, rows).view(*index.shape, -1))
    advanced = per_call_us(lambda: xs[index], 2000)
    selected = per_call_us(lambda: xs.index_select(0, rows).view(*index.shape, -1), 2000)
    print(f"{'gather, advanced indexing xs[index]':64s} {advanced:8.1f} us")
    print(f"{'gather, xs.index_select(0, rows) (as the fit does)':64s} {selected:8.1f} us")
    print(f"ratio={selected / advanced:.2f}")


if __name__ == "__main__":
    main()
