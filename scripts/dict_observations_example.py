"""A PPO on dict observations (``MultiInputPolicy``) watched by oodmon: false alarms and delays.

Run (about a minute on one thread; two with --vec-normalize):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/dict_observations_example.py --out runs/dictobs

Trains PPO (SB3's defaults, seed 0) for 60,000 steps on CartPole-v1 whose observation is a dict,
``{"pole": (angle, angular velocity), "cart": (position, velocity)}`` (flattened in its keys'
order, cart before pole: not the vector's), saves ``ppo.zip`` into ``--out``, then
``oodmon.watch(model, "DictCartPole-v0", env=...)`` fits the learned detectors and calibrates the
threshold (the defaults: 90 and 50 ID episodes, 5% per episode with confidence 0.9), and plays
20 ID episodes (seeds 10,000 on) and 20 episodes whose pole doubles in length at step 20,
through ``MonitoredEnv``s the script steps with ``model.predict`` on the dicts. It prints how many
of each alarmed, and the steps of the shifted episodes' first alarms and ends.

``--vec-normalize``: the PPO trains inside ``VecNormalize(make_vec_env(..., n_envs=4))``, which
normalises both keys (SB3's defaults), and saves ``vecnormalize.pkl`` beside it; oodmon reads the
statistics from that file and the script steps with ``model.predict`` on the dicts normalised by
that VecNormalize, as they were in training.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium
import numpy as np
import torch
from gymnasium import spaces

from oodmon.threads import torch_threads

ENV_ID = "DictCartPole-v0"


class DictCartPole(gymnasium.ObservationWrapper):
    """CartPole (oodmon's, so that a shift can begin mid-episode) with dict observations."""

    def __init__(self, env: gymnasium.Env | None = None) -> None:
        super().__init__(env if env is not None else gymnasium.make("CartPole-v1"))
        box = self.env.observation_space
        self.observation_space = spaces.Dict({"pole": spaces.Box(box.low[2:], box.high[2:]),
                                              "cart": spaces.Box(box.low[:2], box.high[:2])})

    def observation(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        return {"cart": obs[:2].astype(np.float32), "pole": obs[2:].astype(np.float32)}


def play(env: gymnasium.Env, model, seeds: range, venv=None) -> list[tuple[int | None, int]]:
    """Per episode: the step of the first alarm (None: none) and the episode's length; the model
    acts on each dict as ``venv`` (a VecNormalize) normalises it, if given."""
    out = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        first, steps, done = None, 0, False
        while not done:
            seen = obs if venv is None else venv.normalize_obs(obs)
            obs, _, terminated, truncated, info = env.step(model.predict(seen, deterministic=True)[0])
            if first is None and info["oodmon"]["alarm"]:
                first = steps
            steps, done = steps + 1, terminated or truncated
        out.append((first, steps))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/dictobs"))
    parser.add_argument("--steps", type=int, default=60_000, help="PPO's training steps")
    parser.add_argument("--vec-normalize", action="store_true", help="train inside VecNormalize (both keys normalised)")
    args = parser.parse_args()
    torch.set_num_threads(torch_threads(default=1))
    import oodmon
    from oodmon.monitor import MonitoredEnv
    from stable_baselines3 import PPO

    gymnasium.register(ENV_ID, entry_point=DictCartPole, max_episode_steps=500)
    args.out.mkdir(parents=True, exist_ok=True)
    venv = statistics = None
    if args.vec_normalize:
        from stable_baselines3.common.env_util import make_vec_env
        from stable_baselines3.common.vec_env import VecNormalize

        venv = VecNormalize(make_vec_env(ENV_ID, n_envs=4, seed=0))
    model = PPO("MultiInputPolicy", venv if venv is not None else gymnasium.make(ENV_ID), seed=0, device="cpu")
    model.learn(args.steps)
    model.save(args.out / "ppo.zip")
    if venv is not None:
        venv.save(args.out / "vecnormalize.pkl")
        venv.training, statistics = False, args.out / "vecnormalize.pkl"
    watched = oodmon.watch(model, ENV_ID, env=DictCartPole(gymnasium.make("oodmon/CartPole-v1")),
                           vec_normalize=statistics)
    shifted = MonitoredEnv(DictCartPole(gymnasium.make("oodmon/CartPole-v1", length=2.0, onset_step=20)), watched.monitor)
    print(f"threshold {watched.monitor.threshold:.4f} on the {watched.monitor.detector} detector")
    for label, env in (("ID", watched), ("length=2.0 from step 20", shifted)):
        episodes = play(env, model, range(10_000, 10_020), venv)
        alarmed = sum(first is not None for first, _ in episodes)
        print(f"{label}: {alarmed} of {len(episodes)} episodes alarmed; (first alarm, length): {episodes}")


if __name__ == "__main__":
    main()
