"""A PPO trained inside VecFrameStack, watched by oodmon with --frame-stack: the files to try.

Run (under a minute on one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/frame_stack_example.py --out runs/framestack

Trains PPO (SB3's defaults, seed 0) for 60,000 steps on CartPole-v1 inside
``VecFrameStack(DummyVecEnv([...]), 4)``, saves ``ppo.zip`` into ``--out`` and prints its mean return
over 10 ID episodes as oodmon deploys it (``load_sb3(..., frame_stack=4)``). Then watch it with the
docs/your-policy.md's commands and ``--frame-stack 4``::

    oodmon calibrate --sb3 runs/framestack/ppo.zip --env CartPole-v1 --frame-stack 4 --out runs/framestack/t.json
    oodmon validate runs/framestack/t.json --sb3 runs/framestack/ppo.zip --env CartPole-v1 --frame-stack 4 --episodes 100
    oodmon run --sb3 runs/framestack/ppo.zip --env CartPole-v1 --frame-stack 4 --threshold runs/framestack/t.json \\
        --variant cartpole:length=2.0 --onset 20 --episodes 20 --mcap runs/framestack/shifted.mcap
    oodmon replay runs/framestack/shifted.mcap --monitor

``--vec-normalize``: in rl-baselines3-zoo's order instead, ``VecFrameStack(VecNormalize(...,
norm_reward=False), 4)`` (each observation normalised, then stacked), saving the statistics as
``vecnormalize.pkl``; give the commands ``--vec-normalize runs/framestack/vecnormalize.pkl`` too.
It prints the return without the statistics beside (what the model does with raw observations);
about 90 s.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium

from oodmon.agents.evaluation import episode_returns
from oodmon.agents.sb3 import load_sb3
from oodmon.envs.grid import Variant
from oodmon.threads import limit_threads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/framestack"))
    parser.add_argument("--steps", type=int, default=60_000, help="PPO's training steps")
    parser.add_argument("--vec-normalize", action="store_true",
                        help="train inside VecFrameStack(VecNormalize(...)), rl-baselines3-zoo's order")
    args = parser.parse_args()
    limit_threads()
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack, VecNormalize

    args.out.mkdir(parents=True, exist_ok=True)
    venv = DummyVecEnv([lambda: gymnasium.make("CartPole-v1")])
    if args.vec_normalize:
        venv = VecNormalize(venv, norm_reward=False)
    model = PPO("MlpPolicy", VecFrameStack(venv, 4), seed=0, device="cpu")
    model.learn(args.steps)
    model.save(args.out / "ppo.zip")
    statistics = {}
    if args.vec_normalize:
        venv.save(args.out / "vecnormalize.pkl")
        statistics = {"vec_normalize": args.out / "vecnormalize.pkl"}
        _print_return(args.out, "raw observations stacked", vec_normalize="none")
    _print_return(args.out, "observations each normalised, then stacked" if args.vec_normalize
                  else "observations stacked", **statistics)


def _print_return(out: Path, how: str, **statistics) -> None:
    """The saved PPO's mean return over 10 ID episodes as oodmon deploys it, stacked 4 deep."""
    agent = load_sb3([out / "ppo.zip"], "CartPole-v1", frame_stack=4, **statistics)
    returns = episode_returns(agent.act, Variant("cartpole"), 10, seed=100, wrap=agent.wrap)
    print(f"mean return over 10 ID episodes, {how} 4 deep: {returns.mean():.1f}")


if __name__ == "__main__":
    main()
