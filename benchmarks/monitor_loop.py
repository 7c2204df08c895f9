"""Steps per second of a monitored, logged CartPole run beside SB3's plain evaluation loop.

Run: .venv/bin/python benchmarks/monitor_loop.py

Monitored: the shipped CartPole ensemble (K=5) under the Monitor with a threshold, writing MCAP
and RRD files. Plain: stable-baselines3's ``evaluate_policy`` with one member of the same
architecture ([256, 256] DQN), no uncertainty, no logging. Same episodes (seeds), one torch
thread, in this process, each the best of ROUNDS interleaved rounds (single runs of each read
0.92 to 1.62 on one quiet VM). The last line is ratio=<monitored steps/s / plain steps/s>; goal >= 1.0.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import gymnasium
from stable_baselines3 import DQN
from stable_baselines3.common.evaluation import evaluate_policy

import oodmon  # noqa: F401  (registers the envs)
from oodmon.agents import load, zoo_dir
from oodmon.agents.serialization import load_modules
from oodmon.envs import Variant
from oodmon.monitor import McapSink, Monitor, RerunSink
from oodmon.threads import set_threads

EPISODES = 10
ROUNDS = 3


def monitored_steps_per_s(folder: Path) -> float:
    agent = load("cartpole", "ensemble")
    env = Variant("cartpole").make()
    # Warm-up outside the timing: the first run imports the MCAP and Rerun writers (about 1 s,
    # once per process), as SB3 is imported before the plain loop is timed.
    with Monitor(agent, sinks=[McapSink(folder / "warm.mcap"), RerunSink(folder / "warm.rrd")]) as monitor:
        monitor.run_episode(env, seed=0, max_steps=50)
    steps = 0
    start = time.perf_counter()
    with Monitor(agent, threshold=5.0, sinks=[McapSink(folder / "run.mcap"), RerunSink(folder / "run.rrd")]) as monitor:
        for episode in range(EPISODES):
            steps += monitor.run_episode(env, seed=episode).length
    return steps / (time.perf_counter() - start)


def plain_steps_per_s() -> float:
    env = gymnasium.make("oodmon/CartPole-v1")
    model = DQN("MlpPolicy", env, policy_kwargs={"net_arch": [256, 256]}, seed=0, device="cpu")
    # Member 0 of the shipped ensemble, so that the episodes last as long as the monitored ones.
    modules, _ = load_modules(zoo_dir() / "cartpole-ensemble")
    model.policy.q_net.q_net.load_state_dict(modules["members"][0].state_dict())
    evaluate_policy(model, env, n_eval_episodes=1, warn=False)  # warm-up, as above
    start = time.perf_counter()
    _, lengths = evaluate_policy(model, env, n_eval_episodes=EPISODES, deterministic=True,
                                 return_episode_rewards=True, warn=False)
    return sum(lengths) / (time.perf_counter() - start)


def main() -> None:
    set_threads(1)  # torch and numpy's BLAS, as every oodmon command
    monitored = plain = 0.0
    for _ in range(ROUNDS):  # interleaved, best of each: the rounds least disturbed by the machine
        with tempfile.TemporaryDirectory() as folder:
            monitored = max(monitored, monitored_steps_per_s(Path(folder)))
        plain = max(plain, plain_steps_per_s())
    print(f"monitored + logged (ensemble K=5, MCAP + RRD) {monitored:10.0f} steps/s")
    print(f"plain evaluate_policy (one member)            {plain:10.0f} steps/s")
    print(f"ratio={monitored / plain:.2f}")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
