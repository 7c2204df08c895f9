"""A policy-less monitor's step with its checks of what it is given, beside the same step without them.

Run: .venv/bin/python benchmarks/watched_step.py

A monitor that runs no policy (``Monitor(None)``, what ``oodmon.watch_recorded`` returns) is given
each step's observation and the action taken; since 2026-12-08 it checks them (the observation's
shape against the fit's, the action against what the dynamics model reads) before scoring. The
detectors (dynamics, drift, combined) are fitted with ``fit_on_episodes`` on 6 recorded episodes of
a hand-written CartPole controller (seconds) and the alarm calibrated on 22 others; the step is
timed over the 300 steps of a third set's episode, begun afresh each round, with the checks and with
them skipped (the monitor's ``_watched_shape`` cleared), in alternation (``timing.paired_us``: 5
pairs of rounds, each order once per pair), one thread for torch and numpy's BLAS. ``ratio=`` the
step with the checks over the step without; goal <= 1.1.

Measured on 2026-12-08 (AMD EPYC, 2 cores) before this script, by hand over 20 recorded episodes:
37-42 us a step with the checks against 36-37 without, once a whole-number action was checked
without numpy (41-45 us before). This script, first timing the monitor made beside a twin of it:
``ratio=`` 1.09 and 1.06 (36.7 us against 34.5), and 1.07 and 1.06 once the step's words were
made only for a refusal; the check itself costs 0.3 us (``timeit`` of ``_check_given``), and two
twins with the same checks read 1.00: the rest was the two monitors' memory. Two twins, one
without the checks (this script since): 1.02, 1.01 and 1.03 (34.7-35.6 us against 34.5-34.7).
"""

from __future__ import annotations

import argparse
import warnings

import gymnasium
import numpy as np

from oodmon.monitor import Monitor, calibrate_on_episodes, fit_on_episodes
from oodmon.monitor.recorded import FewRecordedStepsWarning
from oodmon.threads import limit_threads
from timing import paired_us  # benchmarks/timing.py, beside this script

STEPS = 300


def controller(obs: np.ndarray) -> int:
    """Push toward where the pole falls (docs/your-policy.md's)."""
    return int(obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1] > 0)


def recorded(count: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` episodes of the controller, ``STEPS`` steps each, as (observations, actions)."""
    env = gymnasium.make("CartPole-v1", max_episode_steps=STEPS)
    episodes = []
    for index in range(count):
        obs, _ = env.reset(seed=seed + index)
        observations, actions, done = [], [], False
        while not done:
            observations.append(obs)
            actions.append(controller(obs))
            obs, _, terminated, truncated, _ = env.step(actions[-1])
            done = terminated or truncated
        episodes.append((np.array(observations), np.array(actions)))
    return episodes


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    limit_threads()
    with warnings.catch_warnings():  # (few steps on purpose: a step's time does not depend on them)
        warnings.simplefilter("ignore", FewRecordedStepsWarning)
        detectors = fit_on_episodes(recorded(6, 0), gymnasium.spaces.Discrete(2), dynamics_updates=200)
    threshold = calibrate_on_episodes(detectors, recorded(22, 100), far=0.1)
    observations, actions = recorded(1, 200)[0]
    steps = list(zip(observations, actions.tolist()))  # (Python ints: a deployment's loop gives those)

    def episode(monitor: Monitor):
        def run() -> None:
            monitor.begin_episode()
            for obs, action in steps:
                monitor.step(obs, action=action)
            monitor.end_episode()
        return run

    # Two twins (each its own copy of the detectors): the monitor made first and a twin of it ran
    # 2-3 us a step apart with the same checks, the copies' memory laid out otherwise
    made = Monitor(None, threshold, detectors=detectors)
    checked, unchecked = made.twin(), made.twin()
    unchecked._watched_shape = None  # the checks skipped: the step as before 2026-12-08
    checked.open()
    unchecked.open()
    us, baseline, ratio = paired_us(episode(checked), episode(unchecked), repeats=10)
    print(f"step with the checks     {us / len(steps):8.1f} us")
    print(f"step without them        {baseline / len(steps):8.1f} us")
    print(f"ratio={ratio:.2f}")


if __name__ == "__main__":
    main()
