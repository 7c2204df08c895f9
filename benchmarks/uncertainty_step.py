"""Microseconds per decision with all K samples, beside one stable-baselines3 predict() call.

Run: .venv/bin/python benchmarks/uncertainty_step.py

Ensemble K=5, MC Dropout and MC DropConnect with 20 samples, on CartPole's [256, 256] DQN MLP,
batch of one observation, one torch thread, all in this process. The last line is
ratio=<worst decision / predict>; the goal is <= 1.0.
"""

from __future__ import annotations

import time

import gymnasium
import numpy as np
import torch
from stable_baselines3 import DQN
from torch import nn

import oodmon  # noqa: F401  (registers the envs)
from oodmon.agents import EnsembleEstimator, MCEstimator, add_dropout, to_dropconnect

REPEATS = 2000


def per_call_us(call, repeats: int = REPEATS) -> float:
    for _ in range(repeats // 10):  # warm-up
        call()
    best = float("inf")
    for _ in range(3):  # best of three rounds: the least disturbed by the rest of the machine
        start = time.perf_counter()
        for _ in range(repeats):
            call()
        best = min(best, (time.perf_counter() - start) / repeats * 1e6)
    return best


def main() -> None:
    torch.set_num_threads(1)
    env = gymnasium.make("oodmon/CartPole-v1")
    obs, _ = env.reset(seed=0)
    members = [DQN("MlpPolicy", env, policy_kwargs={"net_arch": [256, 256]}, seed=s, device="cpu") for s in range(5)]
    heads = [m.policy.q_net.q_net for m in members]
    plain = members[0]

    ensemble = EnsembleEstimator(heads)
    dropout = MCEstimator(add_dropout(nn.Sequential(*heads[0]), 0.1), n_samples=20)
    dropconnect = MCEstimator(to_dropconnect(nn.Sequential(*heads[0]), 0.1), n_samples=20)
    figures = {
        "sb3 predict (one member)": per_call_us(lambda: plain.predict(obs, deterministic=True)),
        "ensemble K=5": per_call_us(lambda: ensemble.estimate(obs)),
        "mc dropout K=20": per_call_us(lambda: dropout.estimate(obs)),
        "mc dropconnect K=20": per_call_us(lambda: dropconnect.estimate(obs), REPEATS // 20),
    }
    for name, us in figures.items():
        print(f"{name:28s} {us:10.1f} us")
    baseline = figures.pop("sb3 predict (one member)")
    print(f"ratio={max(figures.values()) / baseline:.2f}")


if __name__ == "__main__":
    main()
