"""A PPO on dict observations (``MultiInputPolicy``) watched by oodmon: false alarms and delays.

Run (about a minute on one thread; two with --vec-normalize; 4.5 with --camera):
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

``--camera``: the dict also holds a picture, ``"camera"``, 36 x 36 bytes of the cart and the pole
(the PPO reads it through SB3's CNN): the ``dynamics`` detector reads the vectors, ``frames`` the
picture, ``combined`` both; a third set of 20 episodes has a camera that snows from step 20 (5% of
its pixels white; the physics are ID's).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium
import numpy as np
from gymnasium import spaces

from oodmon.threads import limit_threads

ENV_ID = "DictCartPole-v0"


class DictCartPole(gymnasium.ObservationWrapper):
    """CartPole (oodmon's, so that a shift can begin mid-episode) with dict observations;
    ``camera``: with a picture of the cart and the pole too, which snows from step ``snow_from`` on
    if given."""

    def __init__(self, env: gymnasium.Env | None = None, *, camera: bool = False, snow_from: int | None = None) -> None:
        super().__init__(env if env is not None else gymnasium.make("CartPole-v1"))
        box = self.env.observation_space
        keys = {"pole": spaces.Box(box.low[2:], box.high[2:]), "cart": spaces.Box(box.low[:2], box.high[:2])}
        if camera:
            keys["camera"] = spaces.Box(0, 255, (36, 36, 1), np.uint8)
        self.observation_space = spaces.Dict(keys)
        self.camera, self.snow_from, self.steps = camera, snow_from, 0
        self.snow = np.random.default_rng(0)

    def reset(self, **kwargs):
        self.steps = 0
        return super().reset(**kwargs)

    def step(self, action):
        self.steps += 1
        return super().step(action)

    def observation(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        out = {"cart": obs[:2].astype(np.float32), "pole": obs[2:].astype(np.float32)}
        if self.camera:
            out["camera"] = picture(obs)
            if self.snow_from is not None and self.steps >= self.snow_from:
                out["camera"][self.snow.random(out["camera"].shape) < 0.05] = 255
        return out


def picture(obs: np.ndarray) -> np.ndarray:
    """36 x 36 bytes: the cart's position on the bottom row, the pole up from it at its angle."""
    out = np.zeros((36, 36, 1), np.uint8)
    foot = int(np.clip(18 + 6 * obs[0], 0, 35))
    out[31, max(foot - 3, 0):foot + 4, 0] = 128
    for height in range(12):
        out[30 - height, int(np.clip(foot + height * np.sin(obs[2]), 0, 35)), 0] = 255
    return out


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
    parser.add_argument("--camera", action="store_true", help="a picture in the dict too, and a camera that snows")
    args = parser.parse_args()
    if args.camera and args.vec_normalize:
        parser.error("--camera and --vec-normalize: one or the other (VecNormalize would need norm_obs_keys)")
    limit_threads()
    import oodmon
    from oodmon.monitor import MonitoredEnv
    from stable_baselines3 import PPO

    gymnasium.register(ENV_ID, entry_point=DictCartPole, max_episode_steps=500, kwargs={"camera": args.camera})
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
    watched = oodmon.watch(model, ENV_ID, env=DictCartPole(gymnasium.make("oodmon/CartPole-v1"), camera=args.camera),
                           vec_normalize=statistics)
    shifted = {"length=2.0 from step 20": DictCartPole(gymnasium.make("oodmon/CartPole-v1", length=2.0, onset_step=20),
                                                       camera=args.camera)}
    if args.camera:
        shifted["the camera snowing from step 20"] = DictCartPole(gymnasium.make("oodmon/CartPole-v1"), camera=True,
                                                                  snow_from=20)
    print(f"threshold {watched.monitor.threshold:.4f} on the {watched.monitor.detector} detector "
          f"(detectors: {', '.join(watched.monitor.detectors.names)})")
    for label, env in (("ID", watched), *((name, MonitoredEnv(env, watched.monitor)) for name, env in shifted.items())):
        episodes = play(env, model, range(10_000, 10_020), venv)
        alarmed = sum(first is not None for first, _ in episodes)
        print(f"{label}: {alarmed} of {len(episodes)} episodes alarmed; (first alarm, length): {episodes}")


if __name__ == "__main__":
    main()
