"""Alarms of a policy that explores, against the same policy deciding as deployed, with detectors
fitted on its own actions and fitted with some random actions (``fit_explore``).

Run (about 7 minutes on one core; MuJoCo, which `make` installs, for Reacher):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/exploration_alarms.py

Each model is trained here (seeded), then watched as deployed twice (``oodmon.watch``: its
detectors fitted and its threshold calibrated on its deterministic actions, the defaults; and with
``fit_explore=0.1``: the detectors fitted on episodes taking a random action at 10% of their steps,
the threshold calibrated on its deterministic actions as before). Each monitor watches 20 fresh ID
episodes (10 for Reacher) in a ``MonitoredEnv`` three ways: its deterministic actions, a random
action at 5% of its steps (a DQN's final exploration rate), and its sampled actions (``predict(obs,
deterministic=False)``, SB3's default: a PPO's or SAC's exploration while it learns); and as many
shifted episodes with its deterministic actions (CartPole's pole twice as long, Reacher's first
motor at half its strength, gear 100 not 200, from step 30), where it should alarm. Each line: the
episodes alarmed (shifted: at or after the onset, with the median delay), and the median and 99th
percentile of the dynamics detector's per-step score (its log-density surprise at the transition).
Then each model learns on for 4,096 steps and plays 20 (10) ID episodes deterministically under
both monitors, and under a third fitted and calibrated anew on its new policy.

Why (docs/your-policy.md, "Inside SB3"): the detectors learn the world from the deployed policy's
own transitions, in which each state has one action. An action the policy would not take there
leads somewhere the dynamics model never saw it lead, so ``MonitorCallback`` reads a training run's
exploration as a shift, and says so (``ExplorationWarning``); fitted on some random actions, the
model has seen other actions' outcomes.
"""

from __future__ import annotations

import argparse
import warnings

import gymnasium
import numpy as np
from stable_baselines3 import DQN, PPO, SAC

import oodmon
from oodmon.envs import parse_variant
from oodmon.envs.shift import parse_env_shift
from oodmon.monitor import MonitoredEnv, OtherActionsWarning
from oodmon.threads import limit_threads

#: The shifted episodes' onset step.
ONSET = 30

#: The training steps each model learns on after its monitors are made (its policy changes).
LEARNING_ON = 4096


def models(reacher: bool):
    """(name, env id, trained model, its episodes, its shift) for each model measured."""
    length = parse_variant("cartpole:length=2.0")
    yield "DQN", "CartPole-v1", DQN(
        "MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, learning_starts=500, learning_rate=2.3e-3, batch_size=64,
        train_freq=8, gradient_steps=2, target_update_interval=100, exploration_fraction=0.3,
        exploration_final_eps=0.04, policy_kwargs={"net_arch": [64, 64]}).learn(4000), 20, length
    yield "PPO", "CartPole-v1", PPO("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0).learn(30000), 20, length
    if reacher:
        yield "SAC", "Reacher-v5", SAC("MlpPolicy", gymnasium.make("Reacher-v5"), seed=0,
                                       learning_starts=1000).learn(8000), 10, \
            parse_env_shift("Reacher-v5:model.actuator_gear[0][0]=100")


def played(model, env: MonitoredEnv, episodes: int, way: str) -> tuple[int, list[float], list[int]]:
    """Episodes alarmed (at or after :data:`ONSET` where ``way`` is ``shifted``), every step's
    dynamics score, and the shifted episodes' delays, of ``episodes`` episodes acted ``way``."""
    rng = np.random.default_rng(0)
    alarmed, scores, delays = 0, [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=900 + episode)
        done, first, step = False, None, 0
        while not done:
            action, _ = model.predict(obs, deterministic=way != "sampled")
            if way == "random 5%" and rng.random() < 0.05:
                action = env.action_space.sample()
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            scores.append(info["oodmon"]["scores"]["dynamics"])
            if info["oodmon"]["alarm"] and first is None and (way != "shifted" or step >= ONSET):
                first = step
            step += 1
        alarmed += first is not None
        if first is not None and way == "shifted":
            delays.append(first - ONSET)
    return alarmed, scores, delays


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-reacher", action="store_true", help="leave out the SAC on Reacher-v5 (MuJoCo)")
    args = parser.parse_args()
    limit_threads()
    warnings.filterwarnings("ignore", category=OtherActionsWarning)  # (the actions are others on purpose here)
    for name, env_id, model, episodes, shift in models(reacher=not args.no_reacher):
        monitors = {}
        for fit_explore in (0.0, 0.1):
            monitor = monitors[fit_explore] = oodmon.watch(model, env_id, fit_explore=fit_explore)
            for way in ("deterministic", "random 5%", "sampled", "shifted"):
                world = shift.make(onset_step=ONSET) if way == "shifted" else gymnasium.make(env_id)
                report(f"{name} {env_id} fit_explore={fit_explore:g} {way:13s}", model, world, monitor, episodes, way)
        # A model that learns on changes what it does: the states it visits move from those the
        # detectors were fitted on, whatever their fit saw of other actions.
        model.learn(LEARNING_ON, reset_num_timesteps=False)
        monitors["refitted"] = oodmon.watch(model, env_id)
        for fitted, monitor in monitors.items():
            label = "refitted" if fitted == "refitted" else f"fit_explore={fitted:g}"
            report(f"{name} {env_id} {LEARNING_ON:,} steps later, {label:15s}", model, gymnasium.make(env_id),
                   monitor, episodes, "deterministic")


def report(label: str, model, world: gymnasium.Env, monitor, episodes: int, way: str) -> None:
    """Play ``episodes`` episodes of ``world`` acted ``way`` under ``monitor`` and print a line."""
    env = MonitoredEnv(world, monitor.twin())
    env.action_space.seed(0)
    alarmed, scores, delays = played(model, env, episodes, way)
    delay = f"  delay median {np.median(delays):g}" if delays else ""
    print(f"{label} alarmed {alarmed:2d}/{episodes}  dynamics median {np.median(scores):9.2f}  p99 "
          f"{np.percentile(scores, 99):9.2f}  (threshold {monitor.threshold:.4g}, {monitor.detector}){delay}",
          flush=True)


if __name__ == "__main__":
    main()
