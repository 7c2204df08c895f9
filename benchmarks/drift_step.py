"""The drift detector's step beside the dynamics detector's, on the same transitions.

Run: .venv/bin/python benchmarks/drift_step.py

For CartPole (discrete actions) and Pendulum (continuous) a dynamics model is fitted on 6 ID
episodes of a hand-written controller (seconds), and for ``wide`` on 6 episodes of a smooth random
system of 348 readings and 17 actions (a humanoid's lengths); the drift detector reads its residuals; each
``score()`` is timed over the transitions of another episode, one thread for torch and numpy's BLAS,
in alternation (``timing.paired_us``: 5 pairs of rounds, each order once per pair). The drift
detector joins the default set of your own env's detectors, so its step is paid beside the
dynamics detector's at every monitored step. ``ratio_<task>=`` is drift's time over dynamics';
``ratio=`` the larger; goal <= 2.0 (drift costs at most one more dynamics step: it runs the same
forward pass, with buffers of its own, and sums what it leaves). ``ratio_in_set=``: a
``DetectorSet`` of both, as the monitor runs them, over one of the dynamics detector alone (drift
reads the pass the dynamics detector made of the step); ``ratio_in_set_unshared=`` the same with
drift on a copy of the model (its own pass), what the set cost before they shared it.

Measured on 2026-11-29 (the other core busy with a bench): drift on the batch path
(``DynamicsDetector.standardized_residuals`` of one row, then its sum) ``ratio=3.49`` (CartPole
40.2 us against 11.5, Pendulum 2.93); on the dynamics detector's fast forward pass (``_FastNll``,
a copy of its own), its residual math in float32 buffers, the running sum in place:
``ratio=1.74`` twice (CartPole 19.7 us against 11.5), and with its largest magnitude read in one
buffer, ``ratio=1.66`` (CartPole 19.0 us against 11.5, Pendulum 1.58). The rest is that pass
(11 us) and numpy's per-call cost of the dozen small operations after it. In a set, as the monitor
runs them: ``ratio_in_set_unshared=2.50`` with drift's own pass (CartPole 31.9 us against 12.7),
``ratio_in_set=1.64`` once drift read the dynamics detector's pass of the step (20.8 us).
Then drift's own arithmetic in fewer numpy calls (its three sums over the members one float64
product of the pass's outputs and their squares, the window a ring summed afresh by one product,
each residual beside its negative so that one maximum reads the largest magnitude), the same day:
``ratio=1.38-1.40`` (CartPole 15.6 us against 11.3, Pendulum 1.33), ``ratio_in_set=1.39-1.40``
(17.2 us against 12.3), ``ratio_in_set_unshared=2.28``. Drift's step after the pass went from about
8 us to about 5 (in the monitor's loop, ``benchmarks/detector_step.py``'s timers: 9.2 to 6.0).
The wide case, added 2026-11-30: ``ratio_wide=101.26`` (drift 10,586 us against 104; its dense
product of 348 readings' outputs, 151 MB, summed some 10 nonzeros a column), then, that product
sparse past ``drift.DENSE_PRODUCT`` entries, ``ratio_wide=`` 1.95 and 2.03 in two runs (163 us
against 81; ``ratio_in_set_wide=`` 1.94 and 1.96), CartPole and Pendulum unchanged (1.40, 1.36).
"""

from __future__ import annotations

import argparse
import copy

import gymnasium
import numpy as np

from oodmon.monitor.detectors import DetectorSet, DriftDetector, DynamicsDetector, StepContext
from oodmon.monitor.detectors.base import Trajectory
from oodmon.monitor.detectors.fitting import collect
from oodmon.threads import set_threads
from timing import paired_us, print_ratios  # benchmarks/timing.py, beside this script

CONTROLLERS = {
    "cartpole": ("CartPole-v1", 2, lambda obs: int(obs[2] + 0.5 * obs[3] > 0)),
    "pendulum": ("Pendulum-v1", None, lambda obs: np.clip([-2.0 * obs[1] - 0.5 * obs[2]], -2.0, 2.0).astype(np.float32)),
}


WIDE = 348  # readings of the synthetic long observation (gymnasium's Humanoid-v5 has 348)


def wide_episodes(n: int = 7, steps: int = 200) -> list[Trajectory]:
    """Episodes of a smooth random system of ``WIDE`` readings driven by 17 actions (a stand-in for
    a humanoid's observation: what matters here is its length, not its physics)."""
    rng = np.random.default_rng(0)
    episodes = []
    for _ in range(n):
        observations, actions = [rng.normal(size=WIDE)], rng.uniform(-1, 1, (steps, 17)).astype(np.float32)
        for action in actions:
            last = observations[-1]
            observations.append(0.95 * last + 0.1 * np.tanh(last[::-1]) + 0.05 * action.sum() + rng.normal(0, 0.05, WIDE))
        episodes.append(Trajectory(np.asarray(observations, np.float32), actions))
    return episodes


def step_calls(detector, trajectory):
    """A call scoring the trajectory's transitions one after the other, round and round."""
    contexts = [StepContext(trajectory.observations[t + 1], trajectory.actions[t + 1], prev_obs=trajectory.observations[t],
                            prev_action=trajectory.actions[t]) for t in range(len(trajectory.actions) - 1)]
    state = {"t": 0}

    def call():
        detector.score(contexts[state["t"]])
        state["t"] = (state["t"] + 1) % len(contexts)
    return call


def set_calls(detectors, trajectory):
    """As :func:`step_calls`, for a ``DetectorSet`` (a fresh context per call, as the monitor makes one per step)."""
    steps = [(trajectory.observations[t + 1], trajectory.actions[t + 1], trajectory.observations[t],
              trajectory.actions[t]) for t in range(len(trajectory.actions) - 1)]
    state = {"t": 0}

    def call():
        obs, action, prev_obs, prev_action = steps[state["t"]]
        detectors.score(StepContext(obs, action, prev_obs=prev_obs, prev_action=prev_action, scores={}))
        state["t"] = (state["t"] + 1) % len(steps)
    return call


def main() -> None:
    set_threads(1)
    ratios, in_set, unshared = {}, {}, {}
    for task in (*CONTROLLERS, "wide"):  # wide: WIDE readings, synthetic
        if task in CONTROLLERS:
            env_id, n_actions, controller = CONTROLLERS[task]
            episodes, repeats = collect(controller, gymnasium.make(env_id), 7, seed=0), 2000
        else:
            episodes, n_actions, repeats = wide_episodes(), None, 200
        dynamics = DynamicsDetector(n_actions, seed=0).fit(episodes[:6])
        drift = DriftDetector.of(dynamics)
        us, baseline, ratio = paired_us(step_calls(drift, episodes[6]), step_calls(dynamics, episodes[6]), repeats)
        print(f"{task}: drift {us:.1f} us, dynamics {baseline:.1f} us per step")
        ratios[task] = ratio
        alone = DetectorSet([dynamics])
        both = DetectorSet([dynamics, drift])
        us, baseline, in_set[task] = paired_us(set_calls(both, episodes[6]), set_calls(alone, episodes[6]), repeats)
        print(f"{task}: a set of dynamics and drift {us:.1f} us, of dynamics alone {baseline:.1f} us per step")
        both_unshared = DetectorSet([dynamics, DriftDetector.of(dynamics)])
        both_unshared["drift"].model = copy.deepcopy(dynamics)  # after the set linked it: a pass of its own
        us, _, unshared[task] = paired_us(set_calls(both_unshared, episodes[6]), set_calls(alone, episodes[6]), repeats)
        print(f"{task}: the same, drift on a copy of the model {us:.1f} us per step")
    # ratio= last, as every script's last line
    for name, figures in (("ratio_in_set", in_set), ("ratio_in_set_unshared", unshared), ("ratio", ratios)):
        print_ratios(name, figures)


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
