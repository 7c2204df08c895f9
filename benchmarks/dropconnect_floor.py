"""What a full-depth MC DropConnect decision must cost in numpy, beside one SB3 predict().

Run: .venv/bin/python benchmarks/dropconnect_floor.py

The shipped CartPole DropConnect agent (K=20 samples, p=0.02 at every layer of its [256, 256]
MLP) draws the positions of its dropped weights instead of a mask over all of them
(``oodmon.agents.plan``). Its middle layer alone drops about 20 x (active inputs) x 256 x 0.02
weights per decision (with the agent shipped on 2026-11-24: 10,752 at seed 0's first state, where
it is timed; median 12,083 over that episode's 500 states; the agent before it: 11,600 and
12,400). Whatever the code around it, each dropped weight needs at least a uniform draw and its
logarithm (the geometric gap to the next one), a running sum (its position), the weight and the
input it multiplies (two gathers and a product), and an add into its sample's output
(``np.bincount``). This script times exactly those seven numpy calls on that many elements
("floor"; decoding a position into its weight, input and output, a few more calls, is left out),
the agent's whole decision, and ``predict()`` of one plain SB3 DQN of the same size; one torch
thread. The last line is floor_ratio=<floor / predict()>: when it
is near or above 1, ``benchmarks/uncertainty_step.py``'s goal (a decision <= one predict())
cannot be met by this agent in numpy, whatever else is trimmed.
"""

from __future__ import annotations

import gymnasium
import numpy as np
import torch
from stable_baselines3 import DQN

import oodmon  # noqa: F401  (registers the envs)
from oodmon.agents import load
from oodmon.agents.plan import active_inputs, repeat_rows
from timing import per_call_us  # benchmarks/timing.py, beside this script

REPEATS = 1000


def middle_layer_drops(agent, obs: np.ndarray) -> int:
    """How many weights the middle layer drops, on average, at ``obs``: K x active inputs x out x p."""
    estimator = agent.estimator
    ops = estimator._suffix  # Linear(4, 256) ReLU Linear(256, 256) ReLU Linear(256, 2), as numpy ops
    x = repeat_rows(np.asarray(obs, np.float32)[None], estimator.n_samples)  # (K, 1, 4), as the estimator has it
    rng = np.random.default_rng(0)
    hidden = ops[1](ops[0](x, rng), rng)  # after the first DropConnect layer and its ReLU
    active = len(active_inputs(hidden))  # the inputs the middle layer draws masks for
    middle = ops[2]
    return round(estimator.n_samples * active * middle.weight_t.shape[1] * float(middle.p))


def main() -> None:
    torch.set_num_threads(1)
    env = gymnasium.make("oodmon/CartPole-v1")
    obs, _ = env.reset(seed=0)
    agent = load("cartpole", "dropconnect")
    drops = middle_layer_drops(agent, obs)
    rng = np.random.default_rng(0)
    weights = rng.standard_normal(256 * 256).astype(np.float32)
    inputs = rng.standard_normal(20 * 256).astype(np.float32)
    gaps = rng.geometric(0.02, drops)
    # Decoding a position into its weight, input and output is left out (a lower bound): the
    # indices are drawn once here.
    weight_index, input_index = rng.integers(0, len(weights), drops), rng.integers(0, len(inputs), drops)
    slots = rng.integers(0, 20 * 256, drops)

    def floor() -> None:
        uniform = rng.random(drops)
        np.log1p(uniform, out=uniform)
        np.cumsum(gaps)
        terms = weights[weight_index] * inputs[input_index]
        np.bincount(slots, weights=terms, minlength=20 * 256)

    plain = DQN("MlpPolicy", env, policy_kwargs={"net_arch": [256, 256]}, seed=0, device="cpu")
    figures = {
        "sb3 predict (one member)": per_call_us(lambda: plain.predict(obs, deterministic=True), REPEATS),
        "shipped dropconnect decision (K=20)": per_call_us(lambda: agent.estimator.estimate(obs), REPEATS),
        f"floor: {drops} dropped weights": per_call_us(floor, REPEATS),
    }
    for name, us in figures.items():
        print(f"{name:40s} {us:10.1f} us")
    predict = figures["sb3 predict (one member)"]
    print(f"decision_ratio={figures['shipped dropconnect decision (K=20)'] / predict:.2f}")
    print(f"floor_ratio={figures[f'floor: {drops} dropped weights'] / predict:.2f}")


if __name__ == "__main__":
    main()
