"""What a full-depth MC DropConnect decision must cost in numpy, beside one SB3 predict().

Run: .venv/bin/python benchmarks/dropconnect_floor.py

The shipped full-depth DropConnect agents (K=20 samples; CartPole p=0.02 at every layer of its
[256, 256] DQN MLP, Pendulum p=0.05 at every layer of its [400, 300] DDPG actor) draw the positions
of their dropped weights instead of a mask over all of them (``oodmon.agents.plan``). Their middle
layer alone drops about 20 x (active inputs) x out x p weights per decision (CartPole, with the
agent shipped on 2026-11-24: 10,752 at seed 0's first state, where it is timed; median 12,083 over
that episode's 500 states; Pendulum: 70,500 at seed 0's first state, median about 81,000 over
200 states). Whatever the code
around it, each dropped weight needs at least a uniform draw and its logarithm (the geometric gap
to the next one), a running sum (its position), the weight and the input it multiplies (two
gathers and a product), and an add into its sample's output (``np.bincount``): "seven calls" times
exactly those numpy calls on that many elements (decoding a position into its weight, input and
output, a few more calls, is left out). The layer's inputs differ from sample to sample (the layer
before dropped other weights for each), so it also needs the product of its K rows of active inputs
with every weight kept: "K rows' product". "floor" is the two together; then the agent's whole
decision, and ``predict()`` of one plain SB3 model of the same size; one thread for torch and numpy's BLAS.

Lines ``floor_ratio_<task>=<floor / predict()>``; the last line, floor_ratio=, is the larger of
the two. Where a task's floor is near or above 1, ``benchmarks/uncertainty_step.py``'s goal (a
decision <= one predict()) cannot be met by that agent in numpy, whatever else is trimmed.

"gaussian": what an approximation would cost, for comparison. The DropConnect paper's own inference
(Wan et al., 2013, Algorithm 2) draws no mask: each layer's pre-activations are drawn from the
normal distribution with the masked sum's mean and variance (``x @ W`` and ``p / (1 - p) x**2 @
W**2``, W the layer's trained weights), for each of the K rows, through the agent's real weights; its line
``gaussian_ratio_<task>=`` is that time / predict(). It is not what the agents do (their outputs
are exact DropConnect samples), and it still takes two products of K rows per layer and a normal
draw for each of the K rows' outputs of every layer (about 45 us for one hidden layer's (20, 256)).
"""

from __future__ import annotations

import argparse
import gymnasium
import numpy as np
from stable_baselines3 import DDPG, DQN

import oodmon  # noqa: F401  (registers the envs)
from oodmon.agents import load
from oodmon.agents.plan import _DropConnect, active_inputs, repeat_rows
from oodmon.agents.recipes import recipe_for
from oodmon.envs.grid import ENV_IDS
from oodmon.threads import set_threads
from timing import per_call_us, print_figures, print_ratios  # benchmarks/timing.py, beside this script

REPEATS = {"cartpole": 1000, "pendulum": 300}
PLAIN = {"cartpole": DQN, "pendulum": DDPG}


def middle_layer(agent, obs: np.ndarray) -> tuple[int, int, int]:
    """The middle layer at ``obs``: how many inputs are active (not zero in some sample), its
    outputs, and how many weights it drops on average (K x active inputs x out x p)."""
    estimator = agent.estimator
    ops = estimator._suffix  # DropConnect, ReLU, DropConnect (the middle layer), ReLU, DropConnect, as numpy ops
    x = repeat_rows(np.asarray(obs, np.float32)[None], estimator.n_samples)  # (K, 1, obs), as the estimator has it
    rng = np.random.default_rng(0)
    hidden = ops[1](ops[0](x, rng), rng)  # after the first DropConnect layer and its ReLU
    active = len(active_inputs(hidden))  # the inputs the middle layer draws masks for
    middle = ops[2]
    n_out = middle.weight_t.shape[1]
    return active, n_out, round(estimator.n_samples * active * n_out * float(middle.p))


def gaussian_layers(ops) -> list[tuple]:
    """The agent's layers (``ops``, as the estimator compiled them), each DropConnect layer with the
    variance weights of its masked sum, p / (1 - p) W**2 (None for the other layers)."""
    return [(op, np.float32(op.p / (1 - op.p)) * op.weight_t ** 2 if isinstance(op, _DropConnect) else None)
            for op in ops]


def gaussian_samples(layers: list[tuple], obs: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """K outputs of ``gaussian_layers`` at ``obs``, each DropConnect layer's pre-activations drawn
    from the normal of the masked sum's mean and variance."""
    x = np.broadcast_to(np.asarray(obs, np.float32), (k, len(obs)))
    for op, variance_t in layers:
        if variance_t is None:
            x = op(x, rng)
            continue
        # Over every input: picking out the active ones, as the agents do, copies more weight rows
        # than it saves (measured: 193 and 342 us with it, 182 and 272 us without).
        mean = x @ op.weight_t + op.bias  # the masked sum's expectation: the trained weights' product
        x = mean + np.sqrt((x * x) @ variance_t) * rng.standard_normal(mean.shape, dtype=np.float32)
    return x


def task_figures(task: str) -> tuple[dict[str, float], float, float]:
    """The task's timings by label, its floor / predict(), and the Gaussian approximation's / predict()."""
    env = gymnasium.make(ENV_IDS[task])
    obs, _ = env.reset(seed=0)
    agent = load(task, "dropconnect")
    k = agent.estimator.n_samples
    active, n_out, drops = middle_layer(agent, obs)
    n_in = agent.estimator._suffix[2].weight_t.shape[0]
    rng = np.random.default_rng(0)
    weights = rng.standard_normal(n_in * n_out).astype(np.float32)
    inputs = rng.standard_normal(k * n_in).astype(np.float32)
    rows, kept = rng.standard_normal((k, active)).astype(np.float32), weights.reshape(n_in, n_out)[:active]
    gaps = rng.geometric(float(agent.estimator._suffix[2].p), drops)
    # Decoding a position into its weight, input and output is left out (a lower bound): the
    # indices are drawn once here.
    weight_index, input_index = rng.integers(0, len(weights), drops), rng.integers(0, len(inputs), drops)
    slots = rng.integers(0, k * n_out, drops)

    def seven_calls() -> None:
        uniform = rng.random(drops)
        np.log1p(uniform, out=uniform)
        np.cumsum(gaps)
        terms = weights[weight_index] * inputs[input_index]
        np.bincount(slots, weights=terms, minlength=k * n_out)

    net_arch = list(recipe_for(task, "dropconnect").net_arch)
    plain = PLAIN[task]("MlpPolicy", env, policy_kwargs={"net_arch": net_arch}, seed=0, device="cpu")
    figures = {
        f"{task} sb3 predict (one plain model)": per_call_us(lambda: plain.predict(obs, deterministic=True), REPEATS[task]),
        f"{task} shipped dropconnect decision (K={k})": per_call_us(lambda: agent.estimator.estimate(obs), REPEATS[task]),
        f"{task} seven calls: {drops} dropped weights": per_call_us(seven_calls, REPEATS[task]),
        f"{task} K rows' product: ({k}, {active}) x ({active}, {n_out})": per_call_us(lambda: np.matmul(rows, kept),
                                                                                  REPEATS[task]),
    }
    floor = figures[f"{task} seven calls: {drops} dropped weights"] + \
        figures[f"{task} K rows' product: ({k}, {active}) x ({active}, {n_out})"]
    figures[f"{task} floor (the two)"] = floor
    layers = gaussian_layers(agent.estimator._suffix)
    gaussian = per_call_us(lambda: gaussian_samples(layers, obs, k, rng), REPEATS[task])
    figures[f"{task} gaussian (an approximation, K={k})"] = gaussian
    predict = figures[f"{task} sb3 predict (one plain model)"]
    return figures, floor / predict, gaussian / predict


def main() -> None:
    set_threads(1)  # torch and numpy's BLAS, as every oodmon command
    ratios, gaussian = {}, {}
    for task in ("cartpole", "pendulum"):
        figures, ratios[task], gaussian[task] = task_figures(task)
        print_figures(figures, 56)
    for task, ratio in gaussian.items():
        print(f"gaussian_ratio_{task}={ratio:.2f}")
    print_ratios("floor_ratio", ratios)


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
