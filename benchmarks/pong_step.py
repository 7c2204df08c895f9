"""The cost of one monitored Pong decision (all samples) beside one plain forward of the network.

Run: .venv/bin/python benchmarks/pong_step.py

"Monitored" is ``Monitor.step`` (estimate, score, alarm rule, a step record with the frame to a
memory sink); "plain" is one forward of the same network as SB3's Q-network computes it in eval
mode (``predict`` without its bookkeeping). Batch of one observation, one thread for torch and
one for numpy's BLAS (which would otherwise spread a large matrix-vector product, the features
detector's, over both cores).

Each method uses its shipped agent (``oodmon/zoo/pong-<method>``; K=20 samples for MC Dropout and
DropConnect, 5 bootstrapped heads on one torso for the ensemble), on observations of the
DropConnect agent's game: DropConnect's cost depends on the weights, since masks are drawn only
for the inputs of the DropConnect layer that are not zero (most are, after the ReLU). An agent not
in the zoo is built with random weights, whose cost is the same for Dropout and the ensemble but
not for DropConnect. Each figure is the best of many interleaved rounds (ten runs of five rounds
of 100 calls), so that other work on the machine disturbs the ratio as little as it can; still,
run it on a quiet machine (the first line prints the load average).
What a decision costs beyond the plain forward: the K samples of the output layer (Dropout: a
20 x 512 mask from the generator, about 20 us), the mean and std, the Monitor's record, each
dearer than alone because the CNN (6.4 MB of weights in its linear layer) leaves the caches cold:
right after it the ensemble's 3 us heads take 35-46 us. Against that, the monitored torso runs
its layers without ``nn.Module.__call__`` (the same operations, ~40-60 us fewer) and in the
channels-last memory format (~5%). Readings of 2026-11-24, evening (the torso called layer by layer),
interleaved with the code before: 1.19, 1.18, 1.18 against 1.27, 1.32, 1.30.
With the agents' shipped fitted detectors, the same decisions with the ``features`` detector too
(the Mahalanobis distance of the 512 torso features) print ``ratio_with_features=``, and with
``frames`` (Pong's default: five image statistics of the newest frame) ``ratio_with_frames=``
(goal <= 1.5 for both).
The last line is ratio=<worst monitored (spread only) / plain>; the goal is <= 1.3.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import torch

import oodmon  # noqa: F401  (registers the envs)
from oodmon.agents.agent import Agent, load, zoo_names
from oodmon.agents.networks import build_modules, estimator_for
from oodmon.agents.recipes import recipe_for
from oodmon.agents.algorithms import architecture, training_env
from oodmon.monitor import MemorySink, Monitor
from oodmon.monitor.detectors import detectors_for
from oodmon.threads import set_threads
from timing import per_call_us  # benchmarks/timing.py, beside this script

REPEATS, ROUNDS, RUNS = 100, 5, 10
WARMUP_STEPS = 200  # into the game, so that the observation is a typical one


def _agent(method: str, env) -> Agent:
    if f"pong-{method}" in zoo_names():
        return load("pong", method, n_samples=20, seed=0)
    arch = architecture(recipe_for("pong", method), env)
    return Agent(estimator_for(build_modules(arch), arch, n_samples=20), {"task": "pong", "method": method}, None)


def _plain_forward(agent: Agent):
    """One forward of the agent's network as SB3's QNetwork does it: uint8 -> float -> CNN -> head."""
    estimator = agent.estimator
    network = getattr(estimator, "network", None)
    if network is None:  # an ensemble: the torso and one head
        network = torch.nn.Sequential(estimator.torso, torch.nn.Linear(512, 6))
    network = network.eval()

    def forward(obs: np.ndarray) -> None:
        with torch.no_grad():
            network(torch.as_tensor(obs[None]))
    return forward


def main() -> None:
    set_threads(1)  # torch and numpy's BLAS, as every oodmon command
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (other work skews the ratio)")
    env = training_env(recipe_for("pong", "dropconnect"))
    agents = {method: _agent(method, env) for method in ("dropconnect", "dropout", "ensemble")}
    obs, _ = env.reset(seed=0)
    for _ in range(WARMUP_STEPS):
        obs, *_ = env.step(int(agents["dropconnect"].estimator.estimate(obs).action[0]))

    plain = _plain_forward(agents["dropconnect"])
    monitors = {}
    for method, agent in agents.items():
        monitors[method] = Monitor(agent, threshold=1.0, sinks=[MemorySink()])
        shipped = detectors_for(agent)
        for detector in ("features", "frames"):  # frames: Pong's default detector
            if shipped is not None and detector in shipped:
                monitors[f"{method} + {detector}"] = Monitor(agent, threshold=1.0, sinks=[MemorySink()],
                                                             detectors=shipped.subset([detector]))
    for monitor in monitors.values():
        monitor.begin_episode(variant="pong")
    figures: dict[str, float] = {}
    for _ in range(RUNS):  # interleaved, best of all
        for name, call in [("plain forward (Q-network, eval)", lambda: plain(obs))] + [
            (f"monitored {m} (K={agents[m.split()[0]].estimator.n_samples})",
             lambda m=m: monitors[m].step(obs, frame=obs[-1]))
            for m in monitors
        ]:
            figures[name] = min(figures.get(name, float("inf")), per_call_us(call, REPEATS, ROUNDS))
    for name, us in figures.items():
        print(f"{name:44s} {us:10.1f} us")
    baseline = figures.pop("plain forward (Q-network, eval)")
    for detector in ("features", "frames"):
        with_it = [us for name, us in figures.items() if f"+ {detector}" in name]
        if with_it:
            print(f"ratio_with_{detector}={max(with_it) / baseline:.2f}  (goal <= 1.5)")
    print(f"ratio={max(us for name, us in figures.items() if '+' not in name) / baseline:.2f}")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
