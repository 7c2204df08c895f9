"""A PPO trained inside VecNormalize, deployed with and without its observation statistics.

Run (about 15 s on one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/vec_normalize_example.py --out runs/vecnorm

Trains PPO on CartPole-v1 for 60,000 steps in ``VecNormalize(norm_obs=True, norm_reward=True)``
(4 envs, seed 0), saves ``ppo.zip`` and ``vecnormalize.pkl`` into ``--out``, and prints the mean
return over 10 ID episodes (seeds 100-109) of the policy as oodmon deploys it: with the statistics
(``load_sb3(..., vec_normalize=...)``) and without them (``vec_normalize="none"``, the env's own
observations, as oodmon deployed every model before it read the statistics). Then try the files
with docs/your-policy.md's commands (``oodmon calibrate --sb3 runs/vecnorm/ppo.zip --env CartPole-v1
--vec-normalize runs/vecnorm/vecnormalize.pkl ...``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from oodmon.agents.evaluation import episode_returns
from oodmon.agents.sb3 import load_sb3
from oodmon.envs.grid import Variant
from oodmon.threads import limit_threads


def train(out: Path) -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    venv = VecNormalize(make_vec_env("CartPole-v1", n_envs=4, seed=0), norm_obs=True, norm_reward=True)
    model = PPO("MlpPolicy", venv, seed=0, n_steps=256, batch_size=256, n_epochs=10, gae_lambda=0.8, gamma=0.98,
                ent_coef=0.0, learning_rate=1e-3)
    model.learn(60_000)
    model.save(out / "ppo.zip")
    venv.save(out / "vecnormalize.pkl")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/vecnorm"))
    args = parser.parse_args()
    limit_threads()
    args.out.mkdir(parents=True, exist_ok=True)
    train(args.out)
    model = args.out / "ppo.zip"
    with_statistics = load_sb3([model], "CartPole-v1", vec_normalize=args.out / "vecnormalize.pkl")
    without = load_sb3([model], "CartPole-v1", vec_normalize="none")
    returns = [episode_returns(agent.act, Variant("cartpole"), 10, seed=100).mean() for agent in (with_statistics, without)]
    print(f"mean return over 10 ID episodes: {returns[0]:.1f} with the statistics, {returns[1]:.1f} without")


if __name__ == "__main__":
    main()
