"""The cost of one monitored Pong decision (all samples) beside one plain forward of the network.

Run: .venv/bin/python benchmarks/pong_step.py

The networks are built as the Pong recipes build them (Nature CNN; DropConnect at the output
layer with K=20 samples; 5 bootstrapped heads on one torso), with random weights: the cost does
not depend on them. "Monitored" is ``Monitor.step`` (estimate, score, alarm rule, a step record
to a memory sink); "plain" is one forward of SB3's Q-network in eval mode, as ``predict`` does
it. Batch of one observation, one torch thread, in this process. The last line is
ratio=<worst monitored / plain>; the goal is <= 1.3.
"""

from __future__ import annotations

import numpy as np
import torch

import oodmon  # noqa: F401  (registers the envs)
from oodmon.agents.agent import Agent
from oodmon.agents.networks import build_modules, estimator_for
from oodmon.agents.recipes import recipe_for
from oodmon.agents.training import _new_model, _training_env, architecture
from oodmon.monitor import MemorySink, Monitor
from timing import per_call_us  # benchmarks/timing.py, beside this script

REPEATS = 300


def main() -> None:
    torch.set_num_threads(1)
    recipe = recipe_for("pong", "dropconnect")
    env = _training_env(recipe)
    obs, _ = env.reset(seed=0)
    plain = _new_model(recipe, env, seed=0).policy
    plain.set_training_mode(False)
    tensor = torch.as_tensor(obs[None])

    def forward() -> None:
        with torch.no_grad():
            plain.q_net(tensor)

    figures = {"plain forward (SB3 Q-network)": per_call_us(forward, REPEATS)}
    for method in ("dropconnect", "ensemble"):
        arch = architecture(recipe_for("pong", method), env)
        agent = Agent(estimator_for(build_modules(arch), arch, n_samples=20), {"task": "pong", "method": method}, None)
        monitor = Monitor(agent, threshold=1.0, sinks=[MemorySink()])
        monitor.begin_episode(variant="pong")
        figures[f"monitored {method} (K={agent.estimator.n_samples})"] = per_call_us(
            lambda: monitor.step(obs, frame=obs[-1]), REPEATS)
    for name, us in figures.items():
        print(f"{name:36s} {us:10.1f} us")
    baseline = figures.pop("plain forward (SB3 Q-network)")
    print(f"ratio={max(figures.values()) / baseline:.2f}")


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
