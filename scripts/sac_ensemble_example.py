"""Three SAC models on Pendulum-v1, watched by oodmon as one ensemble: the files to try.

Run (about 10 minutes on two cores; each model trains on one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sac_ensemble_example.py --out runs/sac

Trains SAC (SB3's defaults but ``learning_rate=1e-3``, seeds 0, 1, 2) for 20,000 steps each on
Pendulum-v1, in parallel, saves ``sac<k>.zip`` into ``--out`` and prints each one's mean return
over 10 ID episodes as oodmon deploys it. Then watch them with docs/your-policy.md's commands; the first
model acts, the three models' deterministic actions are the ensemble's samples::

    oodmon calibrate --sb3 runs/sac/sac0.zip runs/sac/sac1.zip runs/sac/sac2.zip --env Pendulum-v1 --out runs/sac/t.json
    oodmon validate runs/sac/t.json --sb3 runs/sac/sac0.zip runs/sac/sac1.zip runs/sac/sac2.zip --env Pendulum-v1 \
        --episodes 100 --seed 4242
    oodmon run --sb3 runs/sac/sac0.zip runs/sac/sac1.zip runs/sac/sac2.zip --env Pendulum-v1 --threshold runs/sac/t.json \\
        --variant pendulum:m=5.0 --onset 50 --episodes 10 --mcap runs/sac/m5.mcap
    oodmon replay runs/sac/m5.mcap
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import gymnasium

from oodmon.agents.evaluation import episode_returns
from oodmon.agents.sb3 import load_sb3
from oodmon.envs.grid import Variant
from oodmon.threads import limit_threads


def train(seed: int, out: Path, steps: int) -> Path:
    """One SAC model, trained and saved as ``out/sac<seed>.zip``."""
    limit_threads()
    from stable_baselines3 import SAC

    model = SAC("MlpPolicy", gymnasium.make("Pendulum-v1"), seed=seed, learning_rate=1e-3, device="cpu")
    model.learn(steps)
    model.save(out / f"sac{seed}.zip")
    return out / f"sac{seed}.zip"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/sac"))
    parser.add_argument("--steps", type=int, default=20_000, help="each SAC's training steps")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(max_workers=2) as pool:
        paths = list(pool.map(train, range(3), [args.out] * 3, [args.steps] * 3))
    for path in paths:
        agent = load_sb3([path], "Pendulum-v1")
        returns = episode_returns(agent.act, Variant("pendulum"), 10, seed=100, wrap=agent.wrap)
        print(f"{path.name}: mean return over 10 ID episodes {returns.mean():.1f}")


if __name__ == "__main__":
    main()
