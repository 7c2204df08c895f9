"""Does the dynamics model's cap of 3,000 updates blunt it on a large fit? A PPO's InvertedPendulum.

Run (about two minutes on one thread; the policy: docs/your-policy.md's "In MuJoCo" block trains it):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/dynamics_cap.py runs/pendulum-mujoco.zip

The policy plays 30 ID episodes of 1,000 steps (seeds 1,000 on: 30,000 transitions, what the
monitor's fit of 45,000 steps fits on, two thirds of them), and 5 test episodes of 300 steps per
world (seeds 5,000 on): the ID env, the pole four times as heavy and gravity three times as strong,
each from step 50. For each fit (``DynamicsDetector``'s defaults, capped at 3,000 updates, which
is 50 epochs of 30,000 transitions, or not capped, 100 epochs) and each seed of its weights and
minibatches, it prints each world's per-transition score (the negative log-likelihood per
reading) as the median over the test episodes of the largest in steps 50-59, and the mean over
steps 60-299.

What it showed (2026-12-01, AMD EPYC), steps 50-59 / 60-299 per world:

| fit seed | capped, 8 s a fit | not capped, 15-17 s |
|---|---|---|
| 0 | ID -4.2 / -4.8; heavy 1.0 / -2.9; gravity 17.7 / 114.6 | ID -4.7 / -5.0; heavy 93.1 / 6.9; gravity 690.4 / 210.8 |
| 1 | ID -2.4 / -4.4; heavy -0.2 / -3.4; gravity 3.2 / 155.9 | ID -4.5 / -5.0; heavy 117.6 / 4.1; gravity 586.7 / 302.8 |
| 2 | ID -2.1 / -4.4; heavy 0.3 / -3.2; gravity 3.2 / 168.2 | ID -4.2 / -5.0; heavy 95.7 / 5.1; gravity 710.0 / 260.7 |

Capped, the model is still loose (its ID scores higher) and the heavy pole reads as ID; not
capped, it spikes at the onset. The bench's alarm saw the same: with fitting version 8 (capped)
the heavy pole alarmed 0 of 10 episodes, with the code before (30 epochs at a constant rate) 10
of 10 (results/monitor/README.md). Fitting version 9 (2026-12-02) lifted the cap for every fit
(``--dynamics-updates`` still takes one): docs/your-policy.md's "In MuJoCo" bench then alarmed the heavy
pole 10 of 10, and 5 of 200 ID episodes against 0. The script's "capped" fits pass
``max_updates=3000`` (version 8's default), its "not capped" ones ``None``.
"""

from __future__ import annotations

import argparse
import time

import gymnasium
import numpy as np

from oodmon.envs import parse_env_shift
from oodmon.monitor.detectors.base import Trajectory
from oodmon.monitor.detectors.dynamics import DynamicsDetector
from oodmon.threads import limit_threads

WORLDS = {"ID": None, "heavy pole": "InvertedPendulum-v5:model.body_mass[2]=20.0",
          "gravity": "InvertedPendulum-v5:model.opt.gravity[2]=-30.0"}
FITS = {"capped (3,000 updates)": {"max_updates": 3000}, "not capped (100 epochs)": {"max_updates": None}}


def play(model, spec: str | None, seed: int, steps: int, onset: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """One episode's observations (T + 1) and actions (T) of the deterministic policy."""
    env = parse_env_shift(spec).make(onset_step=onset) if spec else gymnasium.make("InvertedPendulum-v5")
    obs, _ = env.reset(seed=seed)
    observations, actions = [obs], []
    for _ in range(steps):
        action, _ = model.predict(obs, deterministic=True)
        obs, _, terminated, truncated, _ = env.step(action)
        observations.append(obs)
        actions.append(action)
        if terminated or truncated:
            break
    return np.array(observations), np.array(actions)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="the PPO's zip (runs/pendulum-mujoco.zip)")
    parser.add_argument("--seeds", default="0,1,2", help="fit seeds, commas between them")
    args = parser.parse_args()
    limit_threads()  # OODMON_TORCH_THREADS, else one thread
    from stable_baselines3 import PPO

    model = PPO.load(args.model, device="cpu")
    fit = [Trajectory(observations=o, actions=a) for o, a in (play(model, None, 1000 + k, 1000) for k in range(30))]
    tests = {world: [play(model, spec, 5000 + k, 300) for k in range(5)] for world, spec in WORLDS.items()}
    print(f"fit on {sum(len(t.actions) for t in fit)} ID transitions")
    for seed in (int(s) for s in args.seeds.split(",")):
        for label, settings in FITS.items():
            start = time.perf_counter()
            detector = DynamicsDetector(None, seed=seed, **settings).fit(fit)
            took = time.perf_counter() - start
            cells = []
            for world, episodes in tests.items():
                scores = [detector.score_transitions(o[:-1], a, o[1:]) for o, a in episodes]
                cells.append(f"{world} {np.median([s[50:60].max() for s in scores]):.1f} / "
                             f"{np.mean([s[60:].mean() for s in scores]):.1f}")
            print(f"seed {seed}, {label}, {took:.0f} s: " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
