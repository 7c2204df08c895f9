"""Microseconds per decision of your own SB3 policy as oodmon deploys it, beside its own predict().

Run: .venv/bin/python benchmarks/sb3_decision.py

A policy loaded with ``--sb3`` (``oodmon.agents.load_sb3``) acts as SB3's ``predict(obs,
deterministic=True)`` would, action for action; every decision of ``calibrate``, the detectors'
fitting, ``validate``, ``run`` and ``bench --sb3`` is one. Here: untrained PPO (a discrete and a
continuous action space), A2C, DQN, SAC and TD3 models of SB3's default sizes, saved and loaded
as a user's, each decision (``agent.act(obs)``) timed in alternation with ``model.predict(obs,
deterministic=True)`` on the same observations (``timing.paired_us``: 5 pairs of rounds, the
median of their ratios), one thread for torch and numpy's BLAS. Lines ``ratio_<model>=`` are each
decision's time over predict()'s; the last, ``ratio=``, the largest. Goal: <= 0.8 (oodmon's
decision takes at most four fifths of SB3's own; it skips only work predict() repeats at every
call and whose result it already has).
"""

from __future__ import annotations

import argparse
import tempfile
from itertools import cycle
from pathlib import Path

import gymnasium
from stable_baselines3 import A2C, DQN, PPO, SAC, TD3
from timing import paired_us, print_ratios  # benchmarks/timing.py, beside this script

from oodmon.agents.sb3 import load_sb3
from oodmon.threads import set_threads

MODELS = {"ppo_discrete": (PPO, "Acrobot-v1"), "ppo_box": (PPO, "Pendulum-v1"), "a2c": (A2C, "CartPole-v1"),
          "dqn": (DQN, "CartPole-v1"), "sac": (SAC, "Pendulum-v1"), "td3": (TD3, "Pendulum-v1")}
REPEATS = 1000


def main() -> None:
    set_threads(1)
    ratios = {}
    with tempfile.TemporaryDirectory() as folder:
        for name, (algorithm, env_id) in MODELS.items():
            env = gymnasium.make(env_id)
            env.observation_space.seed(0)
            path = Path(folder) / f"{name}.zip"
            algorithm("MlpPolicy", env, seed=0, device="cpu").save(path)
            model, agent = algorithm.load(path, device="cpu"), load_sb3([path], env_id)
            observations = cycle([env.observation_space.sample() for _ in range(100)])
            obs = {"next": next(observations)}

            def ours() -> None:
                agent.act(obs["next"])
                obs["next"] = next(observations)

            def theirs() -> None:
                model.predict(obs["next"], deterministic=True)
                obs["next"] = next(observations)

            us, baseline, ratio = paired_us(ours, theirs, REPEATS)
            print(f"{name + ' (' + env_id + ')':28s} oodmon {us:8.1f} us   predict() {baseline:8.1f} us   ({ratio:.2f})")
            ratios[name] = ratio
    print_ratios("ratio", ratios)


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
