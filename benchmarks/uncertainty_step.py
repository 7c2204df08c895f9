"""Microseconds per decision with all K samples, beside one stable-baselines3 predict() call.

Run: .venv/bin/python benchmarks/uncertainty_step.py

The estimators are built exactly as the shipped CartPole agents are (the recipe's [256, 256]
DQN MLP; Dropout's stochastic layer at the output layer, DropConnect's at every layer with
p = 0.02): ensemble K=5, MC Dropout and MC DropConnect with 20 samples; the baseline is
``model.predict()`` of one plain SB3 DQN member of the same size. Batch of one observation, one
torch thread, all in this process. The last line is ratio=<worst decision / predict>; the goal
is <= 1.0, which the full-depth DropConnect agent does not meet (a mask over every weight of
every sample: see "Full depth" in oodmon/zoo/README.md, and ``benchmarks/dropconnect_floor.py``
for why numpy cannot meet it there); ``ratio_output_layer=`` is the worst of the agents whose
sampling stops at the output layer.
"""

from __future__ import annotations

import gymnasium
import torch
from stable_baselines3 import DQN

import oodmon  # noqa: F401  (registers the envs)
from oodmon.agents.networks import build_modules, estimator_for
from oodmon.agents.recipes import recipe_for
from oodmon.agents.algorithms import architecture
from timing import per_call_us  # benchmarks/timing.py, beside this script

REPEATS = 2000


def main() -> None:
    torch.set_num_threads(1)
    env = gymnasium.make("oodmon/CartPole-v1")
    obs, _ = env.reset(seed=0)
    plain = DQN("MlpPolicy", env, policy_kwargs={"net_arch": [256, 256]}, seed=0, device="cpu")
    figures = {"sb3 predict (one member)": per_call_us(lambda: plain.predict(obs, deterministic=True), REPEATS)}
    full_depth = set()
    for method in ("ensemble", "dropout", "dropconnect"):
        recipe = recipe_for("cartpole", method)
        arch = architecture(recipe, env)
        estimator = estimator_for(build_modules(arch), arch, n_samples=recipe.n_samples)
        depth = "" if method == "ensemble" else " (output layer)" if recipe.last_only else f" (full depth, p={recipe.drop_p:g})"
        label = f"{method} K={estimator.n_samples}{depth}"
        if method != "ensemble" and not recipe.last_only:
            full_depth.add(label)
        figures[label] = per_call_us(lambda: estimator.estimate(obs), REPEATS)
    for name, us in figures.items():
        print(f"{name:40s} {us:10.1f} us")
    baseline = figures.pop("sb3 predict (one member)")
    output_layer = [us for label, us in figures.items() if label not in full_depth]
    print(f"ratio_output_layer={max(output_layer) / baseline:.2f}")
    print(f"ratio={max(figures.values()) / baseline:.2f}")


if __name__ == "__main__":
    main()
