"""Alarms of a policy that explores, against the same policy deciding as deployed.

Run (about 3 minutes on one core; MuJoCo, which `make` installs, for Reacher):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/exploration_alarms.py

Each model is trained here (seeded), then watched as deployed (``oodmon.watch``: its detectors
fitted and its threshold calibrated on its deterministic actions, the defaults), and plays 20
fresh ID episodes (10 for Reacher) in a ``MonitoredEnv`` three ways: its deterministic actions,
a random action at 5% of its steps (a DQN's final exploration rate), and its sampled actions
(``predict(obs, deterministic=False)``, SB3's default: a PPO's or SAC's exploration while it
learns). Each line: the episodes alarmed, and the median and 99th percentile of the dynamics
detector's per-step score (its log-density surprise at the transition).

Why (docs/your-policy.md, "Inside SB3"): the detectors learn the world from the deployed policy's
own transitions, in which each state has one action. An action the policy would not take there
leads somewhere the dynamics model never saw it lead, so ``MonitorCallback`` reads a training run's
exploration as a shift, and says so (``ExplorationWarning``).
"""

from __future__ import annotations

import argparse

import gymnasium
import numpy as np
from stable_baselines3 import DQN, PPO, SAC

import oodmon
from oodmon.monitor import MonitoredEnv
from oodmon.threads import limit_threads


def models(reacher: bool):
    """(name, env id, trained model, its episodes) for each model measured."""
    yield "DQN", "CartPole-v1", DQN(
        "MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, learning_starts=500, learning_rate=2.3e-3, batch_size=64,
        train_freq=8, gradient_steps=2, target_update_interval=100, exploration_fraction=0.3,
        exploration_final_eps=0.04, policy_kwargs={"net_arch": [64, 64]}).learn(4000), 20
    yield "PPO", "CartPole-v1", PPO("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0).learn(30000), 20
    if reacher:
        yield "SAC", "Reacher-v5", SAC("MlpPolicy", gymnasium.make("Reacher-v5"), seed=0,
                                       learning_starts=1000).learn(8000), 10


def played(model, env: MonitoredEnv, episodes: int, way: str) -> tuple[int, list[float]]:
    """Episodes alarmed, and every step's dynamics score, of ``episodes`` ID episodes acted ``way``."""
    rng = np.random.default_rng(0)
    alarmed, scores = 0, []
    for episode in range(episodes):
        obs, _ = env.reset(seed=900 + episode)
        done, alarm = False, False
        while not done:
            action, _ = model.predict(obs, deterministic=way != "sampled")
            if way == "random 5%" and rng.random() < 0.05:
                action = env.action_space.sample()
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            scores.append(info["oodmon"]["scores"]["dynamics"])
            alarm |= info["oodmon"]["alarm"]
        alarmed += alarm
    return alarmed, scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-reacher", action="store_true", help="leave out the SAC on Reacher-v5 (MuJoCo)")
    args = parser.parse_args()
    limit_threads()
    for name, env_id, model, episodes in models(reacher=not args.no_reacher):
        monitor = oodmon.watch(model, env_id)
        for way in ("deterministic", "random 5%", "sampled"):
            env = MonitoredEnv(gymnasium.make(env_id), monitor.twin())
            env.action_space.seed(0)
            alarmed, scores = played(model, env, episodes, way)
            print(f"{name} {env_id} {way:13s} alarmed {alarmed:2d}/{episodes}  dynamics median "
                  f"{np.median(scores):9.2f}  p99 {np.percentile(scores, 99):9.2f}  (threshold "
                  f"{monitor.threshold:.4g}, {monitor.detector})", flush=True)


if __name__ == "__main__":
    main()
